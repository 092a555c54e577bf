/* The controller's step in C, three calls a step (coopsumo/sim/fast.py: sight, decide, after_step) and the vehicle
 * table's advance (advanced_table): each does the arithmetic of its numpy definition in coopsumo/sim/controller.py
 * or vehicle_table.py in the same order, so the results are equal bit for bit (tests/test_fast_step.py); built, like
 * kernels.c, with -ffp-contract=off. */
#include "kernels.h"

/* numpy.maximum and numpy.minimum of two floats: NaN if either is, else the larger (smaller); b when equal, as
 * numpy gives it (the sign of a zero included) */
static inline double np_max(double a, double b) { return (a > b || isnan(a)) ? a : b; }
static inline double np_min(double a, double b) { return (a < b || isnan(a)) ? a : b; }

/* Control parameters as World passes them (controller.Controls.params), one float64 array. */
enum { P_LANES, P_CAR, P_LC_GAP, P_LC_HEADWAY, P_T_CHANGE, P_V_ACC, P_NEWELL_C, P_NEWELL_D, P_A1, P_A2, P_V_CC,
       P_ACC_X, P_ZONE, P_STANDING, P_DT, P_LANE_W, P_VEH_W, P_COUNT };

/* physics.lane_change_safe of one vehicle */
static inline int change_safe(double lead_gap, double follow_gap, double v, double v_follow, const double *p) {
    return lead_gap >= p[P_LC_GAP] + p[P_LC_HEADWAY] * v && follow_gap >= p[P_LC_GAP] + p[P_LC_HEADWAY] * v_follow;
}

/* controller.other_lane of the vehicles nums, from the per-number lane-change state */
static void other_lanes(Py_ssize_t n, const int64_t *nums, const int64_t *lane, const int64_t *lc_from,
                        const int64_t *lc_to, const double *lc_left, int64_t *other) {
    for (Py_ssize_t i = 0; i < n; i++) {
        int64_t at = nums[i];
        other[i] = lc_left[at] > 0 ? lc_from[at] + lc_to[at] - lane[i] : -1;
    }
}

/* controller.nearest_leader of columns c0 and c1 of n x k gaps: numpy.argmin's pick, the first of equal ones */
static inline Py_ssize_t nearer(const double *gap, Py_ssize_t i, Py_ssize_t c0, Py_ssize_t c1, Py_ssize_t k) {
    double g0 = gap[i * k + c0], g1 = gap[i * k + c1];
    return (g1 < g0 || (isnan(g1) && !isnan(g0))) ? c1 : c0;
}

static Py_ssize_t smallest(int count, const Py_ssize_t *sizes) {
    Py_ssize_t out = sizes[0];
    for (int i = 1; i < count; i++)
        out = sizes[i] < out ? sizes[i] : out;
    return out;
}

/* every vehicle number indexes the per-number state arrays (size: the shortest of them) */
static int nums_in_range(Py_ssize_t n, const int64_t *nums, Py_ssize_t size) {
    for (Py_ssize_t i = 0; i < n; i++)
        if (nums[i] < 0 || nums[i] >= size) {
            PyErr_Format(PyExc_IndexError, "vehicle number %lld outside the state arrays (%zd)", (long long)nums[i],
                         size);
            return -1;
        }
    return 0;
}

/* sight(nums, lane, pos, speed, v_exp_all, lc_from_all, lc_to_all, lc_left_all, params, gaps, idx, exists, vec,
 * other, busy, feasible, keys, occ_lane, occ_pos, occ_veh) -> m: controller.sight. The neighbours of each vehicle
 * in its left, own, right and second lane (gaps 4 x n x 4, idx 2 x n x 4, exists n x 4), vec its expected speed,
 * nearest leader's gap and speed (3 x n), the occupancy (room for 2n; m pairs), feasible actions (n x 4). */
PyObject *step_sight(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, 8, 8, 8, 8, 8, 8, -8, -8, -1, -8, -8, -1, -1, -8, -8, -8, -8};
    enum { NUMS, LANE, POS, SPEED, VEXP, FROM, TO, LEFT_S, PARAMS, GAPS, IDX, EXISTS, VEC, OTHER, BUSY, FEAS, KEYS,
           OLANE, OPOS, OVEH, NARGS };
    Py_buffer v[NARGS];
    if (check_count("sight", nargs, NARGS) < 0 || acquire(args, NARGS, sizes, v) < 0)
        return NULL;
    Py_ssize_t n = v[NUMS].len / 8, size = smallest(4, (Py_ssize_t[]){v[VEXP].len / 8, v[FROM].len / 8,
                                                                     v[TO].len / 8, v[LEFT_S].len / 8});
    int ok = v[LANE].len / 8 == n && v[POS].len / 8 == n && v[SPEED].len / 8 == n && v[PARAMS].len / 8 == P_COUNT &&
             v[GAPS].len / 8 == 16 * n && v[IDX].len / 8 == 8 * n && v[EXISTS].len == 4 * n &&
             v[VEC].len / 8 == 3 * n && v[OTHER].len / 8 == n && v[BUSY].len == n && v[FEAS].len == 4 * n &&
             v[KEYS].len / 8 == 2 * n && v[OLANE].len / 8 == 2 * n && v[OPOS].len / 8 == 2 * n &&
             v[OVEH].len / 8 == 2 * n;
    if (!ok) {
        release(NARGS, v);
        return PyErr_Format(PyExc_ValueError, "sight: array lengths do not match");
    }
    const int64_t *nums = v[NUMS].buf, *lane = v[LANE].buf;
    const double *pos = v[POS].buf, *speed = v[SPEED].buf, *p = v[PARAMS].buf;
    double *gaps = v[GAPS].buf, *vec = v[VEC].buf;
    int64_t *idx = v[IDX].buf, *other = v[OTHER].buf;
    uint8_t *busy = v[BUSY].buf, *feasible = v[FEAS].buf;
    if (nums_in_range(n, nums, size) < 0) {
        release(NARGS, v);
        return NULL;
    }
    int64_t *query = malloc(sizeof(int64_t) * (size_t)(4 * n + 1));
    if (query == NULL) {
        release(NARGS, v);
        return PyErr_NoMemory();
    }
    const double *v_exp_all = v[VEXP].buf;
    other_lanes(n, nums, lane, v[FROM].buf, v[TO].buf, v[LEFT_S].buf, other);
    for (Py_ssize_t i = 0; i < n; i++) {
        vec[i] = v_exp_all[nums[i]];
        busy[i] = other[i] >= 0;
        query[4 * i] = lane[i] + 1;
        query[4 * i + 1] = lane[i];
        query[4 * i + 2] = lane[i] - 1;
        query[4 * i + 3] = busy[i] ? other[i] : lane[i];
    }
    Py_ssize_t m = build_occupancy(n, lane, pos, other, v[KEYS].buf, v[OLANE].buf, v[OPOS].buf, v[OVEH].buf);
    if (m < 0) {
        free(query);
        release(NARGS, v);
        return PyErr_NoMemory();
    }
    Py_ssize_t nk = 4 * n;
    double *lead_gap = gaps, *lead_speed = gaps + nk, *follow_gap = gaps + 2 * nk, *follow_speed = gaps + 3 * nk;
    find_neighbours(m, v[KEYS].buf, v[OLANE].buf, v[OVEH].buf, n, 4, pos, speed, query, (int64_t)p[P_LANES],
                    p[P_CAR], lead_gap, lead_speed, follow_gap, follow_speed, idx, idx + nk, v[EXISTS].buf);
    const uint8_t *exists = v[EXISTS].buf;
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_ssize_t c = nearer(lead_gap, i, 1, 3, 4);
        vec[n + i] = lead_gap[4 * i + c];
        vec[2 * n + i] = lead_speed[4 * i + c];
        /* left (side 0) and right (side 2), then speed-up and none */
        for (int side = 0; side <= 2; side += 2) {
            Py_ssize_t at = 4 * i + side;
            feasible[4 * i + side / 2] = !busy[i] && exists[at] &&
                                         change_safe(lead_gap[at], follow_gap[at], speed[i], follow_speed[at], p);
        }
        feasible[4 * i + 2] = 1;
        feasible[4 * i + 3] = 1;
    }
    free(query);
    release(NARGS, v);
    return PyLong_FromSsize_t(m);
}

/* physics.resolve_conflicts of the accepted changes ok (n): by target lane, front first (numpy.lexsort's stable
 * order), the rear one of two entering one lane too close is refused. Returns -1 when out of memory. */
static int resolve_conflicts(Py_ssize_t n, const int64_t *target, const double *pos, const double *speed,
                             uint8_t *ok, const double *p) {
    Py_ssize_t count = 0;
    for (Py_ssize_t i = 0; i < n; i++)
        count += ok[i] != 0;
    if (count < 2)
        return 0;
    Py_ssize_t *order = malloc(sizeof(Py_ssize_t) * (size_t)count);
    if (order == NULL)
        return -1;
    Py_ssize_t k = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        if (!ok[i])
            continue;
        /* insertion sort by (target, -pos); equal keys keep the index order */
        Py_ssize_t j = k++;
        while (j > 0) {
            Py_ssize_t b = order[j - 1];
            int before = target[i] < target[b] || (target[i] == target[b] && -pos[i] < -pos[b]);
            if (!before)
                break;
            order[j] = b;
            j--;
        }
        order[j] = i;
    }
    Py_ssize_t last = -1;
    for (Py_ssize_t j = 0; j < count; j++) {
        Py_ssize_t b = order[j];
        if (last >= 0 && target[last] == target[b]) {
            double gap = pos[last] - p[P_CAR] - pos[b];
            if (gap < p[P_LC_GAP] + p[P_LC_HEADWAY] * speed[b]) {
                ok[b] = 0;
                continue;
            }
        }
        last = b;
    }
    free(order);
    return 0;
}

/* The nearest leader (gap, speed) of each vehicle over the lanes it occupies: controller.leaders_in_occupied_lanes.
 * Returns -1 when out of memory. */
static int leaders_in_occupied_lanes(Py_ssize_t n, const int64_t *lane, const int64_t *other, const double *pos,
                                     const double *speed, const double *p, double *gap, double *v_lead) {
    size_t n2 = (size_t)(2 * n + 1);
    double *f = malloc(sizeof(double) * n2 * 6);
    int64_t *q = malloc(sizeof(int64_t) * n2 * 6);
    uint8_t *exists = malloc(n2);
    if (f == NULL || q == NULL || exists == NULL) {
        free(f);
        free(q);
        free(exists);
        return -1;
    }
    double *keys = f, *occ_pos = f + n2, *lead_gap = f + 2 * n2, *lead_speed = f + 3 * n2;
    double *follow_gap = f + 4 * n2, *follow_speed = f + 5 * n2;
    int64_t *occ_lane = q, *occ_veh = q + n2, *query = q + 2 * n2, *lead_idx = q + 3 * n2, *follow_idx = q + 4 * n2;
    for (Py_ssize_t i = 0; i < n; i++) {
        query[2 * i] = lane[i];
        query[2 * i + 1] = other[i] >= 0 ? other[i] : lane[i];
    }
    Py_ssize_t m = build_occupancy(n, lane, pos, other, keys, occ_lane, occ_pos, occ_veh);
    if (m >= 0) {
        find_neighbours(m, keys, occ_lane, occ_veh, n, 2, pos, speed, query, (int64_t)p[P_LANES], p[P_CAR],
                        lead_gap, lead_speed, follow_gap, follow_speed, lead_idx, follow_idx, exists);
        for (Py_ssize_t i = 0; i < n; i++) {
            Py_ssize_t c = nearer(lead_gap, i, 0, 1, 2);
            gap[i] = lead_gap[2 * i + c];
            v_lead[i] = lead_speed[2 * i + c];
        }
    }
    free(f);
    free(q);
    free(exists);
    return m < 0 ? -1 : 0;
}

#define LEFT 0
#define RIGHT 1
#define SPEEDUP 2
#define UNDECIDED 0
#define HELD 1
#define RELEASED 2

/* decide(nums, lane, pos, speed, v_exp, actions, feasible, leader_gap, leader_speed, lc_left_all, lc_from_all,
 * lc_to_all, hold_all, sent_all, u, params, ok, rejected, target, speeds, changed, p, redraw) -> movers:
 * controller.decide with the accident's draw (p, u, redraw: accident.HoldDraw). The lane
 * changes accepted and refused (target lanes) written into the lane-change state, the accident's hold state
 * updated, the next speeds and whether each differs from the speed last sent. */
PyObject *step_decide(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, 8, 8, 8, 1, 8, 8, -8, -8, -8, -1, 8, 8, 8, -1, -1, -8, -8, -1};
    enum { NUMS, LANE, POS, SPEED, VEXP, ACT, FEAS, LEAD_GAP, LEAD_SPEED, LEFT_S, FROM, TO, HOLD, SENT, U, PARAMS, OK,
           REJ, TARGET, SPEEDS, CHANGED, NBUF, P_HOLD = NBUF, REDRAW, NARGS };
    Py_buffer v[NBUF];
    if (check_count("decide", nargs, NARGS) < 0)
        return NULL;
    double p_hold = PyFloat_AsDouble(args[P_HOLD]);
    int redraw = PyObject_IsTrue(args[REDRAW]);
    if (PyErr_Occurred() || redraw < 0 || acquire(args, NBUF, sizes, v) < 0)
        return NULL;
    Py_ssize_t n = v[NUMS].len / 8;
    Py_ssize_t size = smallest(5, (Py_ssize_t[]){v[LEFT_S].len / 8, v[FROM].len / 8, v[TO].len / 8, v[HOLD].len,
                                                 v[SENT].len / 8});
    int ok_len = v[LANE].len / 8 == n && v[POS].len / 8 == n && v[SPEED].len / 8 == n && v[VEXP].len / 8 == n &&
                 v[ACT].len / 8 == n && v[FEAS].len == 4 * n && v[LEAD_GAP].len / 8 == n &&
                 v[LEAD_SPEED].len / 8 == n &&
                 (p_hold <= 0.0 || v[U].len / 8 == n) &&
                 v[PARAMS].len / 8 == P_COUNT && v[OK].len == n && v[REJ].len == n && v[TARGET].len / 8 == n &&
                 v[SPEEDS].len / 8 == n && v[CHANGED].len == n;
    if (!ok_len) {
        release(NBUF, v);
        return PyErr_Format(PyExc_ValueError, "decide: array lengths do not match");
    }
    const int64_t *nums = v[NUMS].buf, *lane = v[LANE].buf, *actions = v[ACT].buf;
    const double *pos = v[POS].buf, *speed = v[SPEED].buf, *v_exp = v[VEXP].buf, *p = v[PARAMS].buf;
    const double *leader_gap = v[LEAD_GAP].buf, *leader_speed = v[LEAD_SPEED].buf, *sent = v[SENT].buf, *u = v[U].buf;
    const uint8_t *feasible = v[FEAS].buf;
    double *lc_left = v[LEFT_S].buf, *speeds = v[SPEEDS].buf;
    int64_t *lc_from = v[FROM].buf, *lc_to = v[TO].buf, *target = v[TARGET].buf;
    int8_t *hold = v[HOLD].buf;
    uint8_t *ok = v[OK].buf, *rejected = v[REJ].buf, *changed = v[CHANGED].buf;
    if (nums_in_range(n, nums, size) < 0) {
        release(NBUF, v);
        return NULL;
    }
    /* controller.lane_changes: asked for, feasible now, not cutting into another change */
    for (Py_ssize_t i = 0; i < n; i++) {
        int wants = actions[i] == LEFT || actions[i] == RIGHT;
        target[i] = lane[i] + (actions[i] == LEFT ? 1 : -1);
        ok[i] = wants && feasible[4 * i + (wants ? actions[i] : SPEEDUP)];
    }
    double *work = malloc(sizeof(double) * (size_t)(2 * n + 1));
    int64_t *other = malloc(sizeof(int64_t) * (size_t)(n + 1));
    if (work == NULL || other == NULL || resolve_conflicts(n, target, pos, speed, ok, p) < 0) {
        free(work);
        free(other);
        release(NBUF, v);
        return PyErr_NoMemory();
    }
    Py_ssize_t movers = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        int wants = actions[i] == LEFT || actions[i] == RIGHT;
        rejected[i] = wants && !ok[i];
        if (ok[i]) {
            int64_t at = nums[i];
            lc_left[at] = p[P_T_CHANGE];
            lc_from[at] = lane[i];
            lc_to[at] = target[i];
            movers++;
        }
    }
    /* the observation's leaders hold unless a change started (then every vehicle's leader may change) */
    double *gap = work, *v_lead = work + n;
    if (movers) {
        other_lanes(n, nums, lane, lc_from, lc_to, lc_left, other);
        if (leaders_in_occupied_lanes(n, lane, other, pos, speed, p, gap, v_lead) < 0) {
            free(work);
            free(other);
            release(NBUF, v);
            return PyErr_NoMemory();
        }
    } else {
        memcpy(gap, leader_gap, sizeof(double) * (size_t)n);
        memcpy(v_lead, leader_speed, sizeof(double) * (size_t)n);
    }
    double close_base = p[P_A1] * p[P_CAR];
    for (Py_ssize_t i = 0; i < n; i++) {
        int64_t at = nums[i];
        /* accident.hold_and_obstacle */
        double g = gap[i], vl = v_lead[i];
        if (p_hold <= 0.0) {
            if (hold[at] == HELD)
                hold[at] = RELEASED;
        } else {
            int in_zone = pos[i] >= p[P_ACC_X] - p[P_ZONE] && pos[i] < p[P_ACC_X];
            double obstacle = p[P_ACC_X] - pos[i];
            int at_head = obstacle < g && speed[i] < p[P_STANDING];
            int draw = in_zone && (hold[at] == UNDECIDED || (hold[at] == HELD && at_head && redraw));
            if (draw)
                hold[at] = u[i] < p_hold ? HELD : RELEASED;
            if (hold[at] == HELD && obstacle < g) {
                g = obstacle;
                vl = 0.0;
            }
        }
        /* physics.next_speed: eq. (9), then eq. (11), capped at v_exp */
        double accel = actions[i] == SPEEDUP ? p[P_V_ACC] : 0.0;
        double bound = np_max(v_exp[i] * (1.0 - exp(-p[P_NEWELL_C] * g / v_exp[i] - p[P_NEWELL_D])), 0.0);
        double v_new = np_min(np_min(speed[i] + accel, bound), v_exp[i]);
        if (g <= close_base + p[P_A2] * speed[i])
            v_new = np_min(v_new, np_max(vl - p[P_V_CC], 0.0));
        speeds[i] = np_max(v_new, 0.0);
        changed[i] = speeds[i] != sent[at];
    }
    free(work);
    free(other);
    release(NBUF, v);
    return PyLong_FromSsize_t(movers);
}

/* after_step(nums, lane, pos, lc_left_all, lc_from_all, lc_to_all, params, rows) -> count: controller.after_step.
 * Every lane change's clock runs down by one step, then the (follower, leader) rows of vehicles whose bodies
 * (physics.body_lanes) overlap (room for 2 (2n - 1) numbers). */
PyObject *step_after_step(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, -8, 8, 8, 8, -8};
    enum { NUMS, LANE, POS, LEFT_S, FROM, TO, PARAMS, ROWS, NARGS };
    Py_buffer v[NARGS];
    if (check_count("after_step", nargs, NARGS) < 0 || acquire(args, NARGS, sizes, v) < 0)
        return NULL;
    Py_ssize_t n = v[NUMS].len / 8;
    Py_ssize_t size = smallest(3, (Py_ssize_t[]){v[LEFT_S].len / 8, v[FROM].len / 8, v[TO].len / 8});
    if (v[LANE].len / 8 != n || v[POS].len / 8 != n || v[PARAMS].len / 8 != P_COUNT ||
        v[ROWS].len / 8 < 2 * (2 * n - 1)) {
        release(NARGS, v);
        return PyErr_Format(PyExc_ValueError, "after_step: array lengths do not match");
    }
    const int64_t *nums = v[NUMS].buf, *lane = v[LANE].buf, *lc_from = v[FROM].buf, *lc_to = v[TO].buf;
    const double *pos = v[POS].buf, *p = v[PARAMS].buf;
    double *lc_left = v[LEFT_S].buf;
    int64_t *rows = v[ROWS].buf;
    if (nums_in_range(n, nums, size) < 0) {
        release(NARGS, v);
        return NULL;
    }
    size_t n2 = (size_t)(2 * n + 1);
    int64_t *q = malloc(sizeof(int64_t) * n2 * 4);
    double *f = malloc(sizeof(double) * n2 * 2);
    if (q == NULL || f == NULL) {
        free(q);
        free(f);
        release(NARGS, v);
        return PyErr_NoMemory();
    }
    int64_t *first = q, *second = q + n2, *occ_lane = q + 2 * n2, *occ_veh = q + 3 * n2;
    double *keys = f, *occ_pos = f + n2;
    double off_from = (p[P_LANE_W] + p[P_VEH_W]) / 2, on_to_at = (p[P_LANE_W] - p[P_VEH_W]) / 2;
    for (Py_ssize_t i = 0; i < n; i++) {
        int64_t at = nums[i];
        if (lc_left[at] > 0)
            lc_left[at] = np_max(lc_left[at] - p[P_DT], 0.0);
        /* physics.body_lanes */
        double left = lc_left[at];
        double moved = (1.0 - left / p[P_T_CHANGE]) * p[P_LANE_W];
        int busy = left > 0, on_from = moved < off_from, on_to = moved > on_to_at;
        first[i] = busy ? (on_from ? lc_from[at] : lc_to[at]) : lane[i];
        second[i] = busy && on_from && on_to ? lc_to[at] : -1;
    }
    Py_ssize_t m = build_occupancy(n, first, pos, second, keys, occ_lane, occ_pos, occ_veh), count = 0;
    for (Py_ssize_t i = 0; i + 1 < m; i++) {
        if (occ_lane[i + 1] == occ_lane[i] && occ_pos[i + 1] - occ_pos[i] < p[P_CAR] - 1e-6 &&
            occ_veh[i + 1] != occ_veh[i]) {
            rows[2 * count] = occ_veh[i];
            rows[2 * count + 1] = occ_veh[i + 1];
            count++;
        }
    }
    free(q);
    free(f);
    release(NARGS, v);
    if (m < 0)
        return PyErr_NoMemory();
    return PyLong_FromSsize_t(count);
}

/* advanced_table(nums, lane, pos, sent_all, switch_to, arrived, out_nums, out_lane, out_pos, out_speed, dt_s) ->
 * count: vehicle_table.advanced_table. Every row of the table drove one step of dt_s at the speed last sent to it
 * (sent_all, by vehicle number) and is in lane switch_to where that is not -1; the arrived vehicles are left out.
 * Returns the rows written, or -1 (nothing written) when a vehicle was never sent a speed (NaN). */
PyObject *step_advanced_table(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs) {
    static const int sizes[] = {8, 8, 8, 8, 8, 8, -8, -8, -8, -8};
    enum { NUMS, LANE, POS, SENT, SWITCH, ARRIVED, O_NUMS, O_LANE, O_POS, O_SPEED, NBUF, DT = NBUF, NARGS };
    Py_buffer v[NBUF];
    if (check_count("advanced_table", nargs, NARGS) < 0)
        return NULL;
    double dt = PyFloat_AsDouble(args[DT]);
    if (PyErr_Occurred() || acquire(args, NBUF, sizes, v) < 0)
        return NULL;
    Py_ssize_t n = v[NUMS].len / 8, size = v[SENT].len / 8, n_arrived = v[ARRIVED].len / 8;
    if (v[LANE].len / 8 != n || v[POS].len / 8 != n || v[SWITCH].len / 8 != n || v[O_NUMS].len / 8 != n ||
        v[O_LANE].len / 8 != n || v[O_POS].len / 8 != n || v[O_SPEED].len / 8 != n) {
        release(NBUF, v);
        return PyErr_Format(PyExc_ValueError, "advanced_table: array lengths do not match");
    }
    const int64_t *nums = v[NUMS].buf, *lane = v[LANE].buf, *switch_to = v[SWITCH].buf, *arrived = v[ARRIVED].buf;
    const double *pos = v[POS].buf, *sent = v[SENT].buf;
    int64_t *o_nums = v[O_NUMS].buf, *o_lane = v[O_LANE].buf;
    double *o_pos = v[O_POS].buf, *o_speed = v[O_SPEED].buf;
    if (nums_in_range(n, nums, size) < 0) {
        release(NBUF, v);
        return NULL;
    }
    for (Py_ssize_t i = 0; i < n; i++)
        if (isnan(sent[nums[i]])) {
            release(NBUF, v);
            return PyLong_FromLong(-1);
        }
    Py_ssize_t count = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        int gone = 0;
        for (Py_ssize_t j = 0; j < n_arrived && !gone; j++)
            gone = arrived[j] == nums[i];
        if (gone)
            continue;
        double speed = sent[nums[i]];
        o_nums[count] = nums[i];
        o_lane[count] = switch_to[i] >= 0 ? switch_to[i] : lane[i];
        o_pos[count] = pos[i] + speed * dt;
        o_speed[count] = speed;
        count++;
    }
    release(NBUF, v);
    return PyLong_FromSsize_t(count);
}

