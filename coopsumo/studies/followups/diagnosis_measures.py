"""The measures of `coopsumo diagnose`, pure functions on arrays and tables: what a model's greedy choices rest on
(Q-value margins between changing lanes and staying) and how its lane changing grew during training."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from coopsumo.sim.physics import LEFT, NONE, RIGHT, SPEEDUP

NEAR_TIE = 0.05
"""a decision is a near tie when |margin| is below this share of the mean |Q-value of staying|"""
COLUMNS = ("eval_speed_mps", "eval_lane_changes_per_vehicle", "decisions", "change_offered_share",
           "change_chosen_share_of_offered", "margin_median", "margin_abs_median", "chosen_change_margin_median",
           "near_tie_share", "q_stay_mean", "speedup_share", "train_lc_rate_first10pct", "train_lc_rate_last10pct",
           "train_speed_last10pct", "td_loss_last10pct")  # fmt: skip
"""diagnosis.csv's measures in their order: the greedy run's, decision_measures', training_course's"""


def decision_measures(rows: np.ndarray) -> dict[str, Any]:
    """Margins of greedy decisions; rows: one per decision of a vehicle, [Q-values (4), offered (4), action, ...].

    margin: the best offered lane change's Q-value minus the best offered of speed-up and none, over the decisions
    where a lane change was offered (> 0: a change is chosen, without a change margin)."""
    q, mask, action = rows[:, :4], rows[:, 4:8].astype(bool), rows[:, 8].astype(int)
    changes_offered = mask[:, LEFT] | mask[:, RIGHT]
    q_change = np.where(mask[:, [LEFT, RIGHT]], q[:, [LEFT, RIGHT]], -np.inf).max(axis=1)
    q_stay = np.where(mask[:, [SPEEDUP, NONE]], q[:, [SPEEDUP, NONE]], -np.inf).max(axis=1)
    margin = (q_change - q_stay)[changes_offered]
    chose_change = np.isin(action, [LEFT, RIGHT])
    return {
        "decisions": len(rows),
        "change_offered_share": float(changes_offered.mean()),
        "change_chosen_share_of_offered": float(chose_change[changes_offered].mean()),
        "margin_median": float(np.median(margin)),
        "margin_abs_median": float(np.median(np.abs(margin))),
        "chosen_change_margin_median": float(np.median(margin[margin > 0])) if (margin > 0).any() else float("nan"),
        "near_tie_share": float((np.abs(margin) < NEAR_TIE * np.abs(q_stay[changes_offered]).mean()).mean()),
        "q_stay_mean": float(q_stay.mean()),
        "speedup_share": float((action == SPEEDUP).mean()),
    }


def training_course(log: pd.DataFrame) -> dict[str, float]:
    """Lane changes per vehicle in the first and last tenth of a training's log (train_log.csv), and its speed and
    TD loss in the last tenth."""
    lc_rate = log["lane_changes"] / log["vehicles"].clip(lower=1)
    tenth = max(len(log) // 10, 1)
    return {
        "train_lc_rate_first10pct": float(lc_rate[:tenth].mean()),
        "train_lc_rate_last10pct": float(lc_rate[-tenth:].mean()),
        "train_speed_last10pct": float(log["mean_speed_mps"][-tenth:].mean()),
        "td_loss_last10pct": float(pd.to_numeric(log["td_loss"], errors="coerce")[-tenth:].mean()),
    }
