/* The world's per-step loops over vehicles in C: the extension module coopsumo.sim._kernels, called by
 * coopsumo/sim/fast.py.
 *
 * Each function does the arithmetic of its numpy definition in coopsumo/sim/physics.py or reward.py in the same
 * order, so the results are equal bit for bit (tests/test_fast.py); built with -ffp-contract=off so that no
 * multiply-add is fused. Arrays arrive through the buffer protocol, C-contiguous, as fast.py makes them: int64 and
 * float64 (8 bytes an item) and bool (1 byte); outputs are filled in place.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define LANE_KEY 1.0e6 /* physics._LANE_KEY */

/* Acquire the buffers of args[0..count-1]; sizes[i] is the item size asked for, negative when the buffer is written.
 * On failure every buffer taken so far is released and -1 returned with a Python error set. */
static int acquire(PyObject *const *args, Py_ssize_t count, const int *sizes, Py_buffer *views) {
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

static void release(Py_ssize_t count, Py_buffer *views) {
    for (Py_ssize_t i = 0; i < count; i++)
        PyBuffer_Release(&views[i]);
}

static int check_count(const char *name, Py_ssize_t nargs, Py_ssize_t expected) {
    if (nargs != expected) {
        PyErr_Format(PyExc_TypeError, "%s takes %zd arguments, got %zd", name, expected, nargs);
        return -1;
    }
    return 0;
}

/* numpy.searchsorted(keys, x, side="right"): the first index whose key is greater than x */
static Py_ssize_t search_right(const double *keys, Py_ssize_t m, double x) {
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

/* occupancy(lane, pos, other, keys, occ_lane, occ_pos, occ_veh): physics.occupancy into the four outputs (each
 * as long as the vehicles plus the lane changers touching a second lane), sorted by key, stable. */
static PyObject *occupancy(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, -8, -8, -8, -8};
    Py_buffer v[7];
    if (check_count("occupancy", nargs, 7) < 0 || acquire(args, 7, sizes, v) < 0)
        return NULL;
    const int64_t *lane = v[0].buf, *other = v[2].buf;
    const double *pos = v[1].buf;
    double *keys = v[3].buf, *occ_pos = v[5].buf;
    int64_t *occ_lane = v[4].buf, *occ_veh = v[6].buf;
    Py_ssize_t n = v[0].len / 8, m = v[3].len / 8;
    Py_ssize_t extra = 0;
    for (Py_ssize_t i = 0; i < n; i++)
        extra += other[i] >= 0 && other[i] != lane[i];
    if (v[1].len / 8 != n || v[2].len / 8 != n || v[4].len / 8 != m || v[5].len / 8 != m || v[6].len / 8 != m ||
        m != n + extra) {
        release(7, v);
        return PyErr_Format(PyExc_ValueError, "occupancy: array lengths do not match");
    }
    /* unsorted lane, vehicle and key of each entry (the vehicles, then the changers' second lanes), two index
     * arrays for the merge sort */
    int64_t *work = malloc(sizeof(int64_t) * (size_t)(4 * m + 1));
    double *unsorted = malloc(sizeof(double) * (size_t)(m + 1));
    if (work == NULL || unsorted == NULL) {
        free(work);
        free(unsorted);
        release(7, v);
        return PyErr_NoMemory();
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
    release(7, v);
    Py_RETURN_NONE;
}

/* neighbours(keys, occ_lane, occ_veh, pos, speed, query, gaps, idx, exists, n_lanes, car_length_m):
 * physics.neighbours of vehicle r in lane query[r, c] (n x k, row-major) in the sorted occupancy; gaps holds
 * lead gap, lead speed, follow gap, follow speed (4 x n x k), idx lead and follow rows (2 x n x k). */
static PyObject *neighbours(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, 8, 8, 8, -8, -8, -1};
    Py_buffer v[9];
    if (check_count("neighbours", nargs, 11) < 0)
        return NULL;
    int64_t n_lanes = PyLong_AsLongLong(args[9]);
    double car_length_m = PyFloat_AsDouble(args[10]);
    if (PyErr_Occurred() || acquire(args, 9, sizes, v) < 0)
        return NULL;
    const double *keys = v[0].buf, *pos = v[3].buf, *speed = v[4].buf;
    const int64_t *occ_lane = v[1].buf, *occ_veh = v[2].buf, *query = v[5].buf;
    Py_ssize_t m = v[0].len / 8, n = v[3].len / 8, nk = v[5].len / 8;
    Py_ssize_t k = n ? nk / n : 0;
    if (v[1].len / 8 != m || v[2].len / 8 != m || v[4].len / 8 != n || k * n != nk || v[6].len / 8 != 4 * nk ||
        v[7].len / 8 != 2 * nk || v[8].len != nk) {
        release(9, v);
        return PyErr_Format(PyExc_ValueError, "neighbours: array lengths do not match");
    }
    double *lead_gap = v[6].buf, *lead_speed = lead_gap + nk, *follow_gap = lead_gap + 2 * nk;
    double *follow_speed = lead_gap + 3 * nk;
    int64_t *lead_idx = v[7].buf, *follow_idx = lead_idx + nk;
    uint8_t *exists = v[8].buf;
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
    release(9, v);
    Py_RETURN_NONE;
}

/* overlaps(occ_lane, occ_pos, occ_veh, rows, car_length_m) -> count: physics.overlaps, neighbours in one lane of
 * the sorted occupancy whose bodies overlap, written as (follower, leader) rows (room for m - 1). */
static PyObject *overlaps(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, -8};
    Py_buffer v[4];
    if (check_count("overlaps", nargs, 5) < 0)
        return NULL;
    double car_length_m = PyFloat_AsDouble(args[4]);
    if (PyErr_Occurred() || acquire(args, 4, sizes, v) < 0)
        return NULL;
    const int64_t *occ_lane = v[0].buf, *occ_veh = v[2].buf;
    const double *occ_pos = v[1].buf;
    int64_t *rows = v[3].buf;
    Py_ssize_t m = v[0].len / 8, count = 0;
    if (v[1].len / 8 != m || v[2].len / 8 != m || v[3].len / 8 < 2 * (m - 1)) {
        release(4, v);
        return PyErr_Format(PyExc_ValueError, "overlaps: array lengths do not match");
    }
    for (Py_ssize_t i = 0; i + 1 < m; i++) {
        if (occ_lane[i + 1] == occ_lane[i] && occ_pos[i + 1] - occ_pos[i] < car_length_m - 1e-6 &&
            occ_veh[i + 1] != occ_veh[i]) {
            rows[2 * count] = occ_veh[i];
            rows[2 * count + 1] = occ_veh[i + 1];
            count++;
        }
    }
    release(4, v);
    return PyLong_FromSsize_t(count);
}

/* section_crossings(prev_nums, prev_pos, nums, pos, sections_m) -> count: reward.section_crossings, vehicles in
 * both tables (each sorted by number) whose front passed a cross-section, prev_pos < x <= pos, once per section. */
static PyObject *section_crossings(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, 8, 8};
    Py_buffer v[5];
    if (check_count("section_crossings", nargs, 5) < 0 || acquire(args, 5, sizes, v) < 0)
        return NULL;
    const int64_t *prev_nums = v[0].buf, *nums = v[2].buf;
    const double *prev_pos = v[1].buf, *pos = v[3].buf, *sections = v[4].buf;
    Py_ssize_t n_prev = v[0].len / 8, n = v[2].len / 8, n_sections = v[4].len / 8, count = 0, j = 0;
    if (v[1].len / 8 != n_prev || v[3].len / 8 != n) {
        release(5, v);
        return PyErr_Format(PyExc_ValueError, "section_crossings: array lengths do not match");
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        while (j < n_prev && prev_nums[j] < nums[i])
            j++;
        if (j < n_prev && prev_nums[j] == nums[i]) {
            for (Py_ssize_t s = 0; s < n_sections; s++)
                count += prev_pos[j] < sections[s] && sections[s] <= pos[i];
        }
    }
    release(5, v);
    return PyLong_FromSsize_t(count);
}

/* exp_into(x, out): out[i] = exp(x[i]) by the C library, whose bits do not depend on AVX-512. numpy's np.exp takes
 * a vector path on CPUs with AVX-512 that differs from it in the last bit for about 5% of arguments, enough to
 * send a dense run elsewhere (docs/model.md, "The same run on every machine"). */
static PyObject *exp_into(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, -8};
    Py_buffer v[2];
    if (check_count("exp_into", nargs, 2) < 0 || acquire(args, 2, sizes, v) < 0)
        return NULL;
    const double *x = v[0].buf;
    double *out = v[1].buf;
    Py_ssize_t n = v[0].len / 8;
    if (v[1].len / 8 != n) {
        release(2, v);
        return PyErr_Format(PyExc_ValueError, "exp_into: array lengths do not match");
    }
    for (Py_ssize_t i = 0; i < n; i++)
        out[i] = exp(x[i]);
    release(2, v);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"occupancy", (PyCFunction)(void (*)(void))occupancy, METH_FASTCALL, "physics.occupancy into given arrays"},
    {"neighbours", (PyCFunction)(void (*)(void))neighbours, METH_FASTCALL, "physics.neighbours into given arrays"},
    {"overlaps", (PyCFunction)(void (*)(void))overlaps, METH_FASTCALL, "physics.overlaps into given rows"},
    {"section_crossings", (PyCFunction)(void (*)(void))section_crossings, METH_FASTCALL,
     "reward.section_crossings"},
    {"exp_into", (PyCFunction)(void (*)(void))exp_into, METH_FASTCALL, "the C library's exp into a given array"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef kernels_module = {PyModuleDef_HEAD_INIT, "_kernels",
                                            "The world's per-step loops in C (coopsumo.sim.fast)", -1, methods};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&kernels_module); }
