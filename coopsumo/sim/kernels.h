/* What the two C files of the extension module coopsumo.sim._kernels share: taking numpy arrays through the buffer
 * protocol, the sorted occupancy and the neighbour search (physics.occupancy, physics.neighbours). kernels.c holds
 * the physics kernels and the module, step.c the controller's step (controller.sight, decide, after_step). */
#ifndef COOPSUMO_KERNELS_H
#define COOPSUMO_KERNELS_H
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define LANE_KEY 1.0e6 /* physics._LANE_KEY */

/* Acquire the buffers of args[0..count-1]; sizes[i] is the item size asked for, negative when the buffer is written.
 * On failure every buffer taken so far is released and -1 returned with a Python error set. */
static inline int acquire(PyObject *const *args, Py_ssize_t count, const int *sizes, Py_buffer *views) {
    for (Py_ssize_t i = 0; i < count; i++) {
        int writable = sizes[i] < 0;
        if (PyObject_GetBuffer(args[i], &views[i], PyBUF_C_CONTIGUOUS | PyBUF_FORMAT |
                                                       (writable ? PyBUF_WRITABLE : 0)) < 0 ||
            views[i].itemsize != abs(sizes[i])) {
            if (!PyErr_Occurred()) {
                PyErr_Format(PyExc_TypeError, "argument %zd: items of %d bytes expected", i, abs(sizes[i]));
                PyBuffer_Release(&views[i]);
            }
            for (Py_ssize_t j = 0; j < i; j++)
                PyBuffer_Release(&views[j]);
            return -1;
        }
    }
    return 0;
}

static inline void release(Py_ssize_t count, Py_buffer *views) {
    for (Py_ssize_t i = 0; i < count; i++)
        PyBuffer_Release(&views[i]);
}

static inline int check_count(const char *name, Py_ssize_t nargs, Py_ssize_t expected) {
    if (nargs != expected) {
        PyErr_Format(PyExc_TypeError, "%s takes %zd arguments, got %zd", name, expected, nargs);
        return -1;
    }
    return 0;
}

/* numpy.searchsorted(keys, x, side="right"): the first index whose key is greater than x */
static inline Py_ssize_t search_right(const double *keys, Py_ssize_t m, double x) {
    Py_ssize_t lo = 0, hi = m;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (keys[mid] <= x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* numpy.searchsorted(keys, x, side="left"): the first index whose key is at least x */
static inline Py_ssize_t search_left(const double *keys, Py_ssize_t m, double x) {
    Py_ssize_t lo = 0, hi = m;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (keys[mid] < x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* physics.occupancy of n vehicles into keys, occ_lane, occ_pos, occ_veh (room for n plus the changers): every
 * (vehicle, lane) pair, sorted by key, stable. Returns the number of pairs m, or -1 when out of memory. */
static inline Py_ssize_t build_occupancy(Py_ssize_t n, const int64_t *lane, const double *pos, const int64_t *other,
                                  double *keys, int64_t *occ_lane, double *occ_pos, int64_t *occ_veh) {
    Py_ssize_t m = n;
    for (Py_ssize_t i = 0; i < n; i++)
        m += other[i] >= 0 && other[i] != lane[i];
    /* unsorted lane, vehicle and key of each entry (the vehicles, then the changers' second lanes), two index
     * arrays for the merge sort */
    int64_t *work = malloc(sizeof(int64_t) * (size_t)(4 * m + 1));
    double *unsorted = malloc(sizeof(double) * (size_t)(m + 1));
    if (work == NULL || unsorted == NULL) {
        free(work);
        free(unsorted);
        return -1;
    }
    int64_t *e_lane = work, *e_veh = work + m, *src = work + 2 * m, *dst = work + 3 * m;
    Py_ssize_t j = n;
    for (Py_ssize_t i = 0; i < n; i++) {
        e_lane[i] = lane[i];
        e_veh[i] = i;
        if (other[i] >= 0 && other[i] != lane[i]) {
            e_lane[j] = other[i];
            e_veh[j] = i;
            j++;
        }
    }
    for (Py_ssize_t i = 0; i < m; i++) {
        unsorted[i] = (double)e_lane[i] * LANE_KEY + pos[e_veh[i]];
        src[i] = i;
    }
    /* bottom-up merge sort of the indices by key: stable, so the permutation numpy's stable argsort gives */
    for (Py_ssize_t width = 1; width < m; width *= 2) {
        for (Py_ssize_t lo = 0; lo < m; lo += 2 * width) {
            Py_ssize_t mid = lo + width < m ? lo + width : m, hi = lo + 2 * width < m ? lo + 2 * width : m;
            Py_ssize_t a = lo, b = mid, k = lo;
            while (a < mid && b < hi)
                dst[k++] = unsorted[src[b]] < unsorted[src[a]] ? src[b++] : src[a++];
            while (a < mid)
                dst[k++] = src[a++];
            while (b < hi)
                dst[k++] = src[b++];
        }
        int64_t *swap = src;
        src = dst;
        dst = swap;
    }
    for (Py_ssize_t i = 0; i < m; i++) {
        int64_t at = src[i];
        keys[i] = unsorted[at];
        occ_lane[i] = e_lane[at];
        occ_pos[i] = pos[e_veh[at]];
        occ_veh[i] = e_veh[at];
    }
    free(work);
    free(unsorted);
    return m;
}

/* physics.neighbours of vehicle r in lane query[r, c] (n x k, row-major) in the sorted occupancy (m pairs): lead
 * gap, lead speed, follow gap, follow speed, lead and follow rows, whether the lane exists (each n x k). */
static inline void find_neighbours(Py_ssize_t m, const double *keys, const int64_t *occ_lane, const int64_t *occ_veh,
                            Py_ssize_t n, Py_ssize_t k, const double *pos, const double *speed, const int64_t *query,
                            int64_t n_lanes, double car_length_m, double *lead_gap, double *lead_speed,
                            double *follow_gap, double *follow_speed, int64_t *lead_idx, int64_t *follow_idx,
                            uint8_t *exists) {
    for (Py_ssize_t r = 0; r < n; r++) {
        double qp = pos[r];
        for (Py_ssize_t c = 0; c < k; c++) {
            Py_ssize_t i = r * k + c;
            int64_t ql = query[i];
            Py_ssize_t ahead = search_right(keys, m, (double)ql * LANE_KEY + qp);
            Py_ssize_t behind = ahead - 1;
            if (behind >= 0 && occ_veh[behind] == r) /* the vehicle itself: step over it */
                behind -= 1;
            int on_road = ql >= 0 && ql < n_lanes;
            exists[i] = (uint8_t)on_road;
            lead_gap[i] = INFINITY;
            lead_speed[i] = 0.0;
            lead_idx[i] = -1;
            if (ahead < m && occ_lane[ahead] == ql) {
                int64_t at = occ_veh[ahead];
                lead_speed[i] = speed[at];
                if (on_road) {
                    lead_gap[i] = pos[at] - car_length_m - qp;
                    lead_idx[i] = at;
                }
            }
            follow_gap[i] = INFINITY;
            follow_speed[i] = 0.0;
            follow_idx[i] = -1;
            if (behind >= 0 && occ_lane[behind] == ql) {
                int64_t at = occ_veh[behind];
                follow_speed[i] = speed[at];
                if (on_road) {
                    follow_gap[i] = qp - car_length_m - pos[at];
                    follow_idx[i] = at;
                }
            }
        }
    }
}

/* the controller's step (step.c), called from the module's method table */
PyObject *step_sight(PyObject *self, PyObject *const *args, Py_ssize_t nargs);
PyObject *step_decide(PyObject *self, PyObject *const *args, Py_ssize_t nargs);
PyObject *step_after_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs);
PyObject *step_advanced_table(PyObject *self, PyObject *const *args, Py_ssize_t nargs);

#endif
