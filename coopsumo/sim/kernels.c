/* The world's per-step loops over vehicles in C: the extension module coopsumo.sim._kernels, called by
 * coopsumo/sim/fast.py.
 *
 * Each function does the arithmetic of its numpy definition in coopsumo/sim/physics.py or reward.py in the same
 * order, so the results are equal bit for bit (tests/test_fast.py); built with -ffp-contract=off so that no
 * multiply-add is fused. Arrays arrive through the buffer protocol, C-contiguous, as fast.py makes them: int64 and
 * float64 (8 bytes an item) and bool (1 byte); outputs are filled in place.
 */
#include "kernels.h"

/* occupancy(lane, pos, other, keys, occ_lane, occ_pos, occ_veh): physics.occupancy into the four outputs (each
 * as long as the vehicles plus the lane changers touching a second lane), sorted by key, stable. */
static PyObject *occupancy(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, -8, -8, -8, -8};
    Py_buffer v[7];
    if (check_count("occupancy", nargs, 7) < 0 || acquire(args, 7, sizes, v) < 0)
        return NULL;
    const int64_t *lane = v[0].buf, *other = v[2].buf;
    Py_ssize_t n = v[0].len / 8, m = v[3].len / 8;
    Py_ssize_t extra = 0;
    for (Py_ssize_t i = 0; i < n; i++)
        extra += other[i] >= 0 && other[i] != lane[i];
    if (v[1].len / 8 != n || v[2].len / 8 != n || v[4].len / 8 != m || v[5].len / 8 != m || v[6].len / 8 != m ||
        m != n + extra) {
        release(7, v);
        return PyErr_Format(PyExc_ValueError, "occupancy: array lengths do not match");
    }
    Py_ssize_t got = build_occupancy(n, lane, v[1].buf, other, v[3].buf, v[4].buf, v[5].buf, v[6].buf);
    release(7, v);
    if (got < 0)
        return PyErr_NoMemory();
    Py_RETURN_NONE;
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

/* followers_mean(occ_keys, occ_value, lane, other_lane, pos, window_m, out): reward.followers_mean into out, per
 * vehicle the mean value of the occupancy entries behind it within window_m in its own lane and, while it changes
 * lanes, in the second lane; 0 where there is none. The same sums in the same order: a running sum of the values
 * (numpy's cumsum is sequential), each lane's window as the difference of two of its entries. */
static PyObject *followers_mean(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, 8, 8, -8};
    Py_buffer v[6];
    if (check_count("followers_mean", nargs, 7) < 0)
        return NULL;
    PyObject *const bufs[6] = {args[0], args[1], args[2], args[3], args[4], args[6]};
    double window = PyFloat_AsDouble(args[5]);
    if (window == -1.0 && PyErr_Occurred())
        return NULL;
    if (acquire(bufs, 6, sizes, v) < 0)
        return NULL;
    const double *keys = v[0].buf, *value = v[1].buf, *pos = v[4].buf;
    const int64_t *lane = v[2].buf, *other = v[3].buf;
    double *out = v[5].buf;
    Py_ssize_t m = v[0].len / 8, n = v[2].len / 8;
    if (v[1].len / 8 != m || v[3].len / 8 != n || v[4].len / 8 != n || v[5].len / 8 != n) {
        release(6, v);
        return PyErr_Format(PyExc_ValueError, "followers_mean: array lengths do not match");
    }
    double *csum = malloc((size_t)(m + 1) * sizeof(double));
    if (csum == NULL) {
        release(6, v);
        return PyErr_NoMemory();
    }
    csum[0] = 0.0;
    double run = 0.0;
    for (Py_ssize_t k = 0; k < m; k++) {
        run += value[k];
        csum[k + 1] = run;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        double total = 0.0, count = 0.0;
        for (int second = 0; second < 2; second++) {
            int64_t l = second ? other[i] : lane[i];
            if (second && !(other[i] >= 0 && other[i] != lane[i]))
                break;
            double hi_key = (double)l * LANE_KEY + pos[i];
            Py_ssize_t lo = search_left(keys, m, hi_key - window), hi = search_left(keys, m, hi_key);
            total += csum[hi] - csum[lo];
            count += (double)(hi - lo);
        }
        out[i] = count > 0 ? total / count : 0.0;
    }
    free(csum);
    release(6, v);
    Py_RETURN_NONE;
}

/* snapshot(occ_keys, occ_lane, occ_pos, lane, pos, n_lanes, car_length_m, out): observation.snapshot into out, (n, 3,
 * 20) uint8: for the left, own and right lane of each vehicle, cell k (centre pos - 5 + 0.5 + k) is 1 when it lies in
 * [front - car_length_m, front) of one of the 8 occupancy entries after the window's start in that lane, or when the
 * lane is off the road. The same comparisons on the same doubles as the numpy definition. */
static PyObject *snapshot(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, 8, 8, -1};
    Py_buffer v[6];
    if (check_count("snapshot", nargs, 8) < 0)
        return NULL;
    PyObject *const bufs[6] = {args[0], args[1], args[2], args[3], args[4], args[7]};
    long long n_lanes = PyLong_AsLongLong(args[5]);
    if (n_lanes == -1 && PyErr_Occurred())
        return NULL;
    double car = PyFloat_AsDouble(args[6]);
    if (car == -1.0 && PyErr_Occurred())
        return NULL;
    if (acquire(bufs, 6, sizes, v) < 0)
        return NULL;
    const double *keys = v[0].buf, *occ_pos = v[2].buf, *pos = v[4].buf;
    const int64_t *occ_lane = v[1].buf, *lane = v[3].buf;
    uint8_t *out = v[5].buf;
    Py_ssize_t m = v[0].len / 8, n = v[3].len / 8;
    if (v[1].len / 8 != m || v[2].len / 8 != m || v[4].len / 8 != n || v[5].len != n * 3 * 20) {
        release(6, v);
        return PyErr_Format(PyExc_ValueError, "snapshot: array lengths do not match");
    }
    static const int64_t sides[3] = {1, 0, -1}; /* physics.SIDE_OFFSETS: left, own, right */
    for (Py_ssize_t i = 0; i < n; i++) {
        double start = pos[i] - 5.0; /* observation.BEHIND_M */
        for (int side = 0; side < 3; side++) {
            int64_t l = lane[i] + sides[side];
            uint8_t *cells = out + (i * 3 + side) * 20;
            int off_road = l < 0 || l >= n_lanes;
            for (int k = 0; k < 20; k++)
                cells[k] = (uint8_t)off_road;
            if (off_road)
                continue;
            Py_ssize_t first = search_right(keys, m, (double)l * LANE_KEY + start);
            for (Py_ssize_t j = first; j < first + 8 && j < m; j++) { /* observation.MAX_PER_WINDOW */
                if (occ_lane[j] != l)
                    continue;
                double front = occ_pos[j], back = front - car;
                for (int k = 0; k < 20; k++) {
                    double centre = start + 0.5 + (double)k;
                    if (centre >= back && centre < front)
                        cells[k] = 1;
                }
            }
        }
    }
    release(6, v);
    Py_RETURN_NONE;
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
    {"section_crossings", (PyCFunction)(void (*)(void))section_crossings, METH_FASTCALL,
     "reward.section_crossings"},
    {"exp_into", (PyCFunction)(void (*)(void))exp_into, METH_FASTCALL, "the C library's exp into a given array"},
    {"followers_mean", (PyCFunction)(void (*)(void))followers_mean, METH_FASTCALL, "reward.followers_mean"},
    {"snapshot", (PyCFunction)(void (*)(void))snapshot, METH_FASTCALL, "observation.snapshot into a given array"},
    {"sight", (PyCFunction)(void (*)(void))step_sight, METH_FASTCALL, "controller.sight into given arrays"},
    {"decide", (PyCFunction)(void (*)(void))step_decide, METH_FASTCALL, "controller.decide into given arrays"},
    {"after_step", (PyCFunction)(void (*)(void))step_after_step, METH_FASTCALL,
     "controller.after_step into given rows"},
    {"advanced_table", (PyCFunction)(void (*)(void))step_advanced_table, METH_FASTCALL,
     "vehicle_table.advanced_table into given arrays"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef kernels_module = {PyModuleDef_HEAD_INIT, "_kernels",
                                            "The world's per-step loops in C (coopsumo.sim.fast)", -1, methods};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&kernels_module); }
