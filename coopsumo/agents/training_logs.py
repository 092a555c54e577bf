"""A training's logs read back: train_log.csv (a row per logging window, tb_log.LOG_FIELDS) and validation.csv (a row
per validated snapshot, selection.write_table), each checked by its columns' rules (record_schemas' Number, Integer,
Text) before a resume keeps a log's rows (file_checks.resume_problem), before a study reuses a finished training
(studies/engine/trainings.logs_problem) and where a study draws them (validation_table). Issue 82, fifth
probe, G6 and G8: a byte that is not UTF-8, a renamed column or no best snapshot was a traceback in the learning and
protocol studies' figures, a speed of 999 m/s was drawn and a score of 1e9 copied into diagnosis.csv. Without torch:
a study's own process reads them."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from coopsumo.field_rules import digits
from coopsumo.files import read_text
from coopsumo.record_schemas import (
    LOSS_MAX,
    PER_VEHICLE,
    REWARD_MAX,
    SECONDS,
    SHARE,
    SPEED,
    Integer,
    Number,
    RecordError,
    Text,
)
from coopsumo.validation import ALPHA_MIN

LOG_RULES: dict[str, Number | Integer] = {
             "step": Integer(1), "sim_time_s": SECONDS, "td_loss": Number(0.0, LOSS_MAX, blank_ok=True),
             **{name: Number(-REWARD_MAX, REWARD_MAX) for name in ("r_speed", "r_lane_change", "r_flow", "reward")},
             "epsilon": SHARE, "mean_speed_mps": SPEED, "wall_s": SECONDS, "alpha": Number(ALPHA_MIN),
             **{name: Integer(0) for name in ("vehicles", "lane_changes", "lane_changes_rejected", "collisions",
                                              "teleports")}}  # fmt: skip
"""each train_log.csv column's limits (tb_log.LOG_FIELDS, tested to name the same: a window's means and counts)"""

REWARD = Number(-REWARD_MAX, REWARD_MAX, unit="a mean reward")
"""a validation score (the mean reward per vehicle and step of the validation runs: a few units, selection.validate)"""
VALIDATION_RULES: dict[str, Number | Integer | Text] = {
    "step": Integer(0), "score": REWARD, "stage": Text(("all", "screen")), "mean_speed_mps": SPEED,
    "lane_changes_per_vehicle": PER_VEHICLE, "screen_score": Number(-REWARD_MAX, REWARD_MAX, blank_ok=True),
    "screen_mean_speed_mps": Number(0.0, SPEED.high, unit="m/s", blank_ok=True),
    "screen_lane_changes_per_vehicle": Number(0.0, PER_VEHICLE.high, blank_ok=True),
    **{name: Number(0.0, 1.0, blank_ok=True)
       for name in ("share_left", "share_right", "share_speedup", "share_none", "screen_share_none",
                    "change_offered_share", "near_tie_share", "change_chosen_share")},
    "q_gap_median": Number(blank_ok=True),  # Q-values: any finite number
}  # fmt: skip
"""each validation.csv column's limits (selection.write_table); a diagnosis measure a snapshot lacks, and a
two-stage selection's measure a snapshot did not run, is blank"""
VALIDATION_RUNS: dict[str, Number] = {"mean_speed_mps_": Number(0.0, SPEED.high, unit="m/s", blank_ok=True),
                                      "lane_changes_per_vehicle_": Number(0.0, PER_VEHICLE.high, blank_ok=True),
                                      "mean_reward_": Number(-REWARD_MAX, REWARD_MAX, blank_ok=True)}  # fmt: skip
"""the limits of each validation run's columns, by the prefix before the run's name (`mean_speed_mps_t2`)"""
VALIDATION_COLUMNS = ("step", "score", "best", "mean_speed_mps", "lane_changes_per_vehicle", "share_none")
"""what every validation.csv holds and the protocol study reads (its diagnosis and figure); a two-stage selection's
also every screen_ column the figure draws"""
SCREEN_COLUMNS = ("screen_mean_speed_mps", "screen_lane_changes_per_vehicle", "screen_share_none")


def read_log(path: Path) -> tuple[str | None, str | None]:
    """(the text of the log `path`, None); (None, None) when there is none; (None, why) when it cannot be read: not
    a regular file (a named pipe: files.read_text refuses it, never waits on it), not UTF-8 text."""
    try:
        return read_text(path), None
    except FileNotFoundError:
        return None, None
    except UnicodeDecodeError as err:
        return None, f"is not a text file (not UTF-8: byte {err.object[err.start]:#04x} at {err.start})"
    except OSError as err:
        return None, f"cannot be read ({err.strerror or type(err).__name__})"


def _log_step(line: str, row: list[str], width: int) -> int | None:
    """The step of a whole train_log.csv row, None for a row cut short or not one of its rows."""
    return int(row[0]) if line.endswith("\n") and len(row) == width and digits(row[0]) else None


def _cells_problem(names: Sequence[str], row: Sequence[str], rules: Mapping[str, Any], step: int) -> str | None:
    """Why a row's cells break their columns' rules (a column without one is not looked at), or None."""
    for name, cell in zip(names, row, strict=True):
        if (rule := rules.get(name)) is None:
            continue
        if isinstance(rule, Text):
            problem = rule.problem(cell or None)
        else:
            try:
                value = float(cell) if cell else math.nan
            except ValueError:
                value = math.nan
            if cell and not math.isfinite(value) or not cell and not rule.blank_ok:
                return f"has {name} = {cell!r} in its row of step {step}, not a finite number"
            problem = rule.problem(value)
        if problem is not None:
            return f"has {name} = {cell!r} in its row of step {step}: it {problem}"
    return None


def log_problem(path: Path, step: int, whole: bool = False) -> str | None:
    """Why the rows of train_log.csv (at path) that a resume from `step` keeps cannot be trusted, or None: its header
    train's own; each row's cells inside LOG_RULES (the loss may be blank: no update in its window), the steps
    rising, no row that is not one between them. A missing log is no problem (it is begun again); the rows past
    `step` and a last row cut short are truncate_log's to drop. whole: the log of a finished training of `step`
    steps, read back whole: a row past its last step or cut short is a problem too."""
    text, problem = read_log(path)
    return problem if text is None else log_text_problem(text, step, whole)


def log_text_problem(text: str, step: int, whole: bool = False) -> str | None:
    """log_problem of a train_log.csv's text."""
    from coopsumo.agents.tb_log import LOG_FIELDS  # (the log's writer imports the world's types: not on every read)

    lines = text.splitlines(keepends=True)
    rows = list(csv.reader(lines))
    if not rows or tuple(rows[0]) != LOG_FIELDS:
        shown = ",".join(rows[0])[:60] if rows else "none (an empty file)"
        return f"has the header {shown!r}, not train's {','.join(LOG_FIELDS)[:60]}..."
    steps = [_log_step(line, row, len(LOG_FIELDS)) for line, row in zip(lines[1:], rows[1:], strict=True)]
    last = 0
    for at, (row, row_step) in enumerate(zip(rows[1:], steps, strict=True)):
        if row_step is None:  # kept only as a last row cut short by a kill, or past the step (both dropped)
            if whole or any(s is not None and s <= step for s in steps[at + 1:]):
                return f"has a row that is not one of its rows after that of step {last}: {','.join(row)[:40]!r}"
            break
        if row_step > step:
            if whole:
                return f"has a row of step {row_step}, past its training's {step} steps"
            break
        if row_step <= last:
            return f"has the row of step {row_step} after that of step {last} (a row twice, or out of order)"
        last = row_step
        if (problem := _cells_problem(LOG_FIELDS, row, LOG_RULES, row_step)) is not None:
            return problem
    return None


def validation_problem(path: Path, steps: int | None = None, selected: Any = None) -> str | None:
    """Why the validation.csv of a finished training (at path) cannot be read back, or None (none there: a training
    that does not select its model has none): its columns VALIDATION_COLUMNS (and a two-stage selection's
    SCREEN_COLUMNS); each row whole, its cells inside VALIDATION_RULES and VALIDATION_RUNS, its step from 0 to the
    training's `steps` (when known), rising; exactly one row marked best (True or False in every row), that of
    the training's `selected` step (its train_summary.json's selected_step, when known)."""
    text, problem = read_log(path)
    return problem if text is None else validation_text_problem(text, steps, selected)


def validation_text_problem(text: str, steps: int | None = None, selected: Any = None) -> str | None:
    """validation_problem of a validation.csv's text."""
    rows = list(csv.reader(io.StringIO(text)))
    names = rows[0] if rows else []
    required = VALIDATION_COLUMNS + (SCREEN_COLUMNS if any(n.startswith("screen_") for n in names) else ())
    if missing := [n for n in required if n not in names]:
        return f"has no column {missing[0]} (its columns: {','.join(names)[:60] or 'none, an empty file'})"
    rules = {**{n: rule for n in names for prefix, rule in VALIDATION_RUNS.items() if n.startswith(prefix)},
             **VALIDATION_RULES}  # fmt: skip
    best, last = [], -1
    for row in rows[1:]:
        if len(row) != len(names) or not digits(row[0]):
            return f"has a row that is not one of its rows after that of step {last}: {','.join(row)[:40]!r}"
        step = int(row[0])
        if step <= last:
            return f"has the row of step {step} after that of step {last} (a row twice, or out of order)"
        if steps is not None and step > steps:
            return f"has a row of step {step}, past its training's {steps} steps"
        last = step
        cells = dict(zip(names, row, strict=True))
        if (problem := _cells_problem(names, row, rules, step) or _row_problem(cells, step)) is not None:
            return problem
        if (mark := row[names.index("best")]) not in ("True", "False"):
            return f"has best = {mark[:20]!r} in its row of step {step}, not True or False"
        if mark == "True":
            best.append(step)
    if last < 0:
        return "has no row"
    if len(best) != 1:
        return f"has {len(best)} rows marked best (steps {best[:3]}), not one: the snapshot model.pt holds"
    if isinstance(selected, int) and not isinstance(selected, bool) and best[0] != selected:
        return f"marks the snapshot of step {best[0]} best, but model.pt holds step {selected} (train_summary.json)"
    return None


ROUNDING = 1e-5
"""how far (relative to the largest of them) a validation.csv row's mean may lie from its runs' mean: the table
writes each to 6 significant digits (selection.write_table's %.6g)"""
RUN_MEANS = (("score", "mean_reward_"), ("mean_speed_mps", "mean_speed_mps_"),
             ("lane_changes_per_vehicle", "lane_changes_per_vehicle_"))
"""a validation.csv row's measures that are its runs' means (selection.validate), and the prefix of its runs'"""
SHARES = ("share_left", "share_right", "share_speedup", "share_none")
"""the shares of the greedy decisions by action (selection.diagnosis): every decision is one of these"""


def _row_problem(row: Mapping[str, str], step: int) -> str | None:
    """Why a validation.csv row (its cells inside their rules) contradicts itself, or None: a score, mean speed or
    lane changes per vehicle that is not the mean of the row's own runs' (selection.validate: the runs the row holds,
    its blank ones not run), action shares that do not sum to 1, lane changes beside no lane change ever chosen (a
    change starts only from a decision to change, each logged: selection.diagnosis). Issue 82, probe 14, F10: a
    speed of 30 m/s beside runs of 23.8, 17.4 and 19.7, shares summing to 1.5, were copied into diagnosis.csv."""
    def number(name: str) -> float:
        return float(row[name]) if row.get(name) else math.nan

    for name, prefix in RUN_MEANS:
        runs = [number(n) for n in row if n.startswith(prefix) and row[n]]
        if runs and not abs(number(name) - sum(runs) / len(runs)) <= ROUNDING * max(map(abs, [*runs, number(name)])):
            return (f"has {name} = {row[name]} in its row of step {step}, not the mean of its runs' "
                    f"{prefix}* ({sum(runs) / len(runs):.6g}): edited?")  # fmt: skip
    shares = [number(n) for n in SHARES]
    if all(math.isfinite(x) for x in shares) and not abs(sum(shares) - 1.0) <= len(SHARES) * ROUNDING:
        return f"has action shares ({', '.join(SHARES)}) summing to {sum(shares):.6g} in its row of step {step}, not 1"
    if number("lane_changes_per_vehicle") > 0 and number("share_left") == 0 and number("share_right") == 0:
        return (f"has lane_changes_per_vehicle = {row['lane_changes_per_vehicle']} in its row of step {step} beside "
                "share_left and share_right 0: no lane change was ever chosen")  # fmt: skip
    return None


SPEED_TOLERANCE = 1e-3
"""how far (relative) a training's mean speed may lie outside its log rows' means: the log rounds them to 6 digits"""


def log_summary_problem(path: Path, summary: Any, steps: int) -> str | None:
    """Why a finished training's train_log.csv at `path` (its rows inside LOG_RULES: log_problem) disagrees with its
    train_summary.json `summary` (its last world's, of summary["steps"] of the training's `steps`), or None: its last
    row the training's last step, holding that world's collisions and teleports and at most its departed vehicles on
    the road; the lane changes (started, refused) of the rows whose window lies in that world at most the summary's,
    the same when the training is one world, and then the summary's mean speed within its rows' means. A value the
    summary lacks is not compared (train_summary_problem judges it). Issue 82, probe 8, J20: a one-row log of 69.9
    m/s and 5000 lane changes beside a summary of 15.33 m/s and 54 was drawn into the learning study's figures."""
    text, _ = read_log(path)
    rows = list(csv.DictReader(io.StringIO(text))) if text is not None and isinstance(summary, dict) else []
    if not rows:
        return None
    said = {k: float(v) for k, v in summary.items() if isinstance(v, int | float) and not isinstance(v, bool)}
    last, world = rows[-1], int(said.get("steps", steps))
    if int(last["step"]) != steps:
        return f"ends with the row of step {last['step']}, not its training's last step {steps}"
    for log_key, key in (("collisions", "collisions"), ("teleports", "teleports"), ("vehicles", "departed")):
        if key in said and (float(last[log_key]) > said[key] if log_key == "vehicles" else
                            float(last[log_key]) != said[key]):  # fmt: skip
            return (f"has {log_key} = {last[log_key]} in its row of step {steps}, but train_summary.json says {key} "
                    f"= {said[key]:g}")  # fmt: skip
    starts = [0, *(int(row["step"]) for row in rows[:-1])]
    inside = [row for row, start in zip(rows, starts, strict=True) if start >= steps - world]  # in its last world
    for key in ("lane_changes", "lane_changes_rejected"):
        total = sum(int(float(row[key])) for row in inside)
        if key in said and (total > said[key] or (world == steps and total != said[key])):
            return (f"has {key} summing to {total} over its rows of steps {steps - world + 1}-{steps} (its training's "
                    f"last world), but train_summary.json says {said[key]:g}")  # fmt: skip
    speeds = [float(row["mean_speed_mps"]) for row in rows]
    mean = said.get("mean_speed_mps")
    if world == steps and mean is not None and not (min(speeds) * (1 - SPEED_TOLERANCE) <= mean
                                                    <= max(speeds) * (1 + SPEED_TOLERANCE)):  # fmt: skip
        return (f"has mean_speed_mps from {min(speeds):g} to {max(speeds):g} m/s in its rows, but train_summary.json "
                f"says {mean:g} m/s for the same steps")  # fmt: skip
    return None


def _table(path: Path, problem_of: Callable[[str], str | None]) -> Any:
    """The CSV log `path` as a pandas table once problem_of(its text) finds nothing; None when there is none;
    RecordError naming the file and the field otherwise."""
    import pandas as pd

    text, problem = read_log(path)
    if text is not None:
        problem = problem_of(text)
    if problem is not None:
        raise RecordError(f"{path} {problem}")
    return None if text is None else pd.read_csv(io.StringIO(text))


def validation_table(path: Path, steps: int | None = None, selected: Any = None) -> Any:
    """A finished training's validation.csv (validation_problem) as a pandas table; None when there is none;
    RecordError naming the file and the field when it breaks its rules."""
    return _table(path, lambda text: validation_text_problem(text, steps, selected))
