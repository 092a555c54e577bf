"""Whether a training folder holds a model a study may reuse: whole, the training's own, its records and logs as it
wrote them (the model store trains and resumes: model_store.train_shared)."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from coopsumo.config import first_difference, results_view
from coopsumo.errors import why_unreadable
from coopsumo.files import read_json
from coopsumo.record_schemas import STORE_CONFIG


class Fault(NamedTuple):
    """Why a training folder holds no model a study may use (training_fault): the path it names, why (a phrase
    after it), and whether finished_training says so (a folder with no model.pt, or another training's, is silent:
    it is simply trained)."""

    what: Path
    why: str
    said: bool


def finished_training(out: Path, config: dict[str, Any], quiet: bool = False) -> dict[str, Any] | None:
    """The training summary of a training without evaluation that finished in out with exactly this config
    (its run marker lists its files, its config.json holds config, model.pt and train_summary.json exist);
    None otherwise (with one line on stderr, unless quiet, when the model itself is the problem or when a folder holding
    a model.pt lost or spoiled its marker, config.json or train_summary.json: training_fault). A cell killed after its
    training but before its record was written reuses it."""
    found = training_fault(out, config)
    if isinstance(found, Fault):
        if not quiet and found.said:
            print(f"coopsumo: {found.what} {found.why}; training it again", file=sys.stderr)
        return None
    return found


def training_fault(out: Path, config: dict[str, Any]) -> dict[str, Any] | Fault:
    """finished_training's judgement of the folder `out` for the training `config`: its train_summary.json, or the
    Fault that keeps its model from being used. Shared with the studies that reuse a cell of that model
    (unusable_trainings), so that a cell is reused only beside the model a training would reuse (issue 82, probe 13,
    F9: a model deleted, swapped or damaged in the store left every cell of a finished study reused)."""
    from coopsumo.run_dirs import RUN_MARKER, listed_files

    read: dict[str, Any] = {}
    for name in (RUN_MARKER, "config.json", "train_summary.json"):
        try:
            read[name] = read_json(out / name)
        except (OSError, ValueError) as err:  # said for a finished training's folder that lost or spoiled it
            has_model, why = (out / "model.pt").is_file(), why_unreadable(err)
            return Fault(out, f"holds a model.pt but its {name} is missing or unreadable ({why})" if has_model
                         else f"has no readable {name} ({why})", has_model)  # fmt: skip
    if (problem := STORE_CONFIG.problem(read["config.json"])) is not None:  # as `coopsumo models` judges it
        return Fault(out, f"holds a model.pt but its config.json {problem}", (out / "model.pt").is_file())
    marker, stored, summary = read[RUN_MARKER], read["config.json"]["config"], read["train_summary.json"]
    listed = listed_files(marker) if isinstance(marker, dict) and marker.get("kind") == "train" else None
    if not (listed is not None and "model.pt" in listed and (out / "model.pt").is_file()):
        return Fault(out, "holds no finished training's model.pt (missing, or not listed by its run marker)", False)
    if not isinstance(summary, dict):
        return Fault(out, f"holds a model.pt but its train_summary.json is {type(summary).__name__}, not an object",
                     True)  # fmt: skip
    if (problem := model_folder_problem(out)) is not None:  # a model that does not load or is not this training's
        return Fault(out / "model.pt", problem, True)
    if results_view(stored) != results_view(json.loads(json.dumps(config))):
        return Fault(out, "holds the model of another training than the study's (its config.json differs)", False)
    if (problem := train_summary_problem(summary, config)) is not None:  # a study would copy its values
        return Fault(out, problem, True)
    if (found := logs_problem(out, config, summary)) is not None:  # a study draws them (the protocol)
        return Fault(out / found[0], found[1], True)
    return summary


def unusable_trainings(root: Path, specs: Sequence[dict[str, Any]], prog: str) -> set[str]:
    """The cells of `specs` (records otherwise reusable) whose training's link, ROOT/train/<training>, leads to a
    folder whose model a training would not reuse (training_fault: model.pt deleted, another training's model.pt
    swapped in, config.json, train_summary.json or the run marker damaged): each is run again, which trains (or
    re-links) its model, with one line per training naming the file and why. Scenario I asks the same of the store
    before its accident runs (model_store.stored_model). A training that has no link there (a study committed without
    its models) is not judged; a link that leads elsewhere is model_store.repointed_trainings'."""

    def problem(link: Path, config: dict[str, Any]) -> tuple[Path, str] | None:
        if not link.is_symlink() or not link.is_dir():
            return None
        found = training_fault(link, config)
        return (found.what, found.why) if isinstance(found, Fault) else None

    return rerun_cells(root, specs, prog, problem, "which train it again")


def logs_problem(out: Path, config: dict[str, Any], summary: Any) -> tuple[str, str] | None:
    """(the log's file name, why) when a log of the finished training `config` in `out` cannot be read back as it
    ran, else None: its train_log.csv whole and inside training_logs.LOG_RULES up to its configuration's last step
    (training_logs.log_problem) and agreeing with `summary`, its train_summary.json (log_summary_problem; issue 82,
    probe 8, J20), its validation.csv (a training that selects its model) inside VALIDATION_RULES, its best snapshot
    the one model.pt holds. The protocol study draws the one and copies the other (issue
    82, fifth probe, G6 and G8): a model whose logs break them is trained again, as one whose train_summary.json
    does, not reused into a study that then stops at its figure or draws 999 m/s. A log that is missing is none
    (finished_run faults a listed file that was deleted)."""
    from coopsumo.agents.training_logs import log_problem, log_summary_problem, validation_problem

    steps = config.get("sim", {}).get("steps") if isinstance(config.get("sim"), dict) else None
    if not isinstance(steps, int) or isinstance(steps, bool):
        return None  # not a training's configuration: the caller compared it with the study's
    log = out / "train_log.csv"
    if (problem := log_problem(log, steps, whole=True) or log_summary_problem(log, summary, steps)) is not None:
        return "train_log.csv", problem
    selected = summary.get("selected_step") if isinstance(summary, dict) else None
    if (problem := validation_problem(out / "validation.csv", steps, selected)) is not None:
        return "validation.csv", problem
    return None


def spoiled_logs(root: Path, specs: Sequence[dict[str, Any]], prog: str) -> set[str]:
    """The cells of `specs` (records otherwise reusable) whose training, ROOT/train/<training>, has a log that cannot
    be read back (logs_problem): each is run again, which trains its model again (finished_training faults the same
    log), with one line per training naming the log and its cells. A study that draws its trainings' logs (the
    protocol) asks before its cells run: a reused cell's training was not looked at again."""
    from coopsumo.files import read_json_object

    def problem(folder: Path, config: dict[str, Any]) -> tuple[Path, str] | None:
        found = logs_problem(folder, config, read_json_object(folder / "train_summary.json")) if folder.is_dir() \
            else None  # fmt: skip
        return None if found is None else (folder / found[0], found[1])

    return rerun_cells(root, specs, prog, problem, "which train it again")


def rerun_cells(root: Path, specs: Sequence[dict[str, Any]], prog: str,
                problem: Callable[[Path, dict[str, Any]], tuple[Path, str] | None], then: str) -> set[str]:  # fmt: skip
    """The keys of the cells of `specs` whose training, ROOT/train/<training> with its training configuration,
    `problem` faults ((what it names, why), or None), with one line per such training naming it, why, its cells
    and what their rerun does (`then`)."""
    cells: dict[Path, tuple[dict[str, Any], list[str]]] = {}
    for spec in specs:
        config = spec["config"].get("train") if isinstance(spec.get("config"), dict) else None
        if isinstance(config, dict):
            folder = root / "train" / str(spec.get("train_key") or spec["key"])
            cells.setdefault(folder, (config, []))[1].append(spec["key"])
    keys = set()
    for folder, (config, names) in cells.items():
        if (found := problem(folder, config)) is None:
            continue
        shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
        print(f"{prog}: {found[0]} {found[1]}; rerunning the {len(names)} cells of its training ({shown}), {then}",
              file=sys.stderr)  # fmt: skip
        keys.update(names)
    return keys


def train_summary_problem(summary: dict[str, Any], config: dict[str, Any]) -> str | None:
    """Why a finished training's train_summary.json cannot stand for its model, or None: a value the studies copy
    missing or not a number, or one no run gives (records.training_problem: record_schemas.TRAIN_SUMMARY_KEYS and
    RUN_SUMMARY's limits, a speed of 999 m/s, negative updates), its last world's steps not its configuration's (the
    last episode's when it trains in episodes), or a selected step that is not one of the training's steps (0 to its
    configuration's sim.steps). The studies copy these values into their tables (scenario II's runs.csv refuses them
    there): a model whose summary breaks them is trained again, not reused into a study that then stops at its table
    on every rerun or copies a blank."""
    from coopsumo.studies.engine.records import training_problem

    if (problem := training_problem(summary, "train_summary.json")) is not None:
        return problem
    steps, step = config.get("sim", {}).get("steps"), summary.get("selected_step", 0)
    if (last := _last_world_steps(config)) is not None and summary["steps"] != last:
        return f"has train_summary.json steps = {json.dumps(summary['steps'])[:20]}, not its last world's {last}"
    if isinstance(steps, int) and (isinstance(step, bool) or not isinstance(step, int) or not 0 <= step <= steps):
        return f"has train_summary.json selected_step = {json.dumps(step)[:20]}, not a step from 0 to its {steps}"
    if (problem := counts_problem(summary, config)) is not None:
        return problem
    if (found := train_values_problem(summary, config)) is not None:
        return f"has train_summary.json {found[0]} = {summary[found[0]]:g}, {found[1]}"
    return None


def train_values_problem(values: dict[str, Any], config: dict[str, Any]) -> tuple[str, str] | None:
    """(the key, why) when one of the values a study copies from the summary of the training `config` (values'
    mean_speed_mps, lane_changes, updates: any of them; NaN is none) is more than that training can give, or None: a
    mean speed above its road's speed limit and fastest desired speed (config.fastest_mps), more updates than
    updates_per_learn per step, more lane changes than the vehicles its road holds at once (one a car length) could
    make one after another (a change takes control.t_change_s) plus one for each vehicle that can depart (one per
    lane and step). Issue 82, probe 13, F6: a part's runs.csv with a training speed of 60 m/s on a 33.34 m/s road,
    1e9 updates or 1e8 lane changes was merged."""
    from coopsumo.config import fastest_mps

    try:
        sim, per_round = config["sim"], int(config["dqn"]["updates_per_learn"])
        road, control, steps = sim["road"], sim["control"], int(sim["steps"])
        lanes, fastest = int(road["lanes"]), fastest_mps(sim)
        held = lanes * float(road["length_m"]) / float(control["car_length_m"])
        changes = held * steps * float(control["dt_s"]) / float(control["t_change_s"]) + steps * lanes
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return None  # not a training's configuration: the caller compared it with the study's
    bounds = {"mean_speed_mps": (fastest + 0.01, f"above any vehicle's speed on its road ({fastest:g} m/s)"),
              "updates": (steps * per_round, f"more than {per_round} per step of its {steps} steps"),
              "lane_changes": (changes, f"more than the {held:g} vehicles its road holds could make in {steps} steps")}
    for key, (most, why) in bounds.items():
        value = values.get(key)
        if isinstance(value, int | float) and not isinstance(value, bool) and float(value) > most:  # NaN: False
            return key, why
    return None


WALL_FACTOR = 2.0
"""how far a training's wall_seconds may lie from its steps over its steps_per_second (both rounded) before the pair
is no training's"""


def counts_problem(summary: dict[str, Any], config: dict[str, Any]) -> str | None:
    """Why a training's summary (its values finite numbers: records.training_problem) holds counts or a wall time its
    own training cannot give, or None: more departures than one per lane and step of its last world, more lane
    changes than its departed vehicles could start in that world one after another (a change takes
    control.t_change_s: run_checks.most_lane_changes; issue 82, probe 14, F9: 5000 for 24 vehicles in 30 s were
    reused), more gradient updates than updates_per_learn per training step,
    a wall time more than WALL_FACTOR times off the training's steps over its steps_per_second (issue 82, probe 8,
    J9: departed and lane_changes of 99999 and 1e9 updates for 200 steps on 2 lanes, or 500000 s beside 126.7
    steps/s, were reused and copied into runs.csv)."""
    sim, dqn = (part if isinstance(part := config.get(name), dict) else {} for name in ("sim", "dqn"))
    road = sim["road"] if isinstance(sim.get("road"), dict) else {}
    lanes, steps, per_round = road.get("lanes"), sim.get("steps"), dqn.get("updates_per_learn")
    last, departed = summary["steps"], summary["departed"]
    if isinstance(lanes, int) and departed > last * lanes:
        return (f"has train_summary.json departed = {departed:g}, more than one vehicle per lane and step of its "
                f"last world ({last} steps on {lanes} lanes)")  # fmt: skip
    if isinstance(control := sim.get("control"), dict) and summary["lane_changes"] > (most := _most_changes(
            departed, last, control)):  # fmt: skip
        return (f"has train_summary.json lane_changes = {summary['lane_changes']:g}, more than its {departed:g} "
                f"vehicles could make in its last world's {last} steps (a change takes {control['t_change_s']:g} s: "
                f"at most {most:g})")  # fmt: skip
    if isinstance(steps, int) and isinstance(per_round, int) and summary["updates"] > steps * per_round:
        return (f"has train_summary.json updates = {summary['updates']:g}, more than {per_round} per step of its "
                f"{steps} steps")  # fmt: skip
    wall, rate = summary["wall_seconds"], summary["steps_per_second"]
    if isinstance(steps, int) and wall > 0.1 and not steps / WALL_FACTOR <= wall * rate <= steps * WALL_FACTOR:
        return (f"has train_summary.json wall_seconds = {wall:g}, but steps_per_second = {rate:g} makes its {steps} "
                f"steps {steps / rate if rate > 0 else math.inf:g} s")  # fmt: skip
    return None


def _most_changes(departed: float, steps: int, control: dict[str, Any]) -> float:
    """run_checks.most_lane_changes of `departed` vehicles over `steps` steps of the control settings `control`
    (inf when they cannot be read: the configuration is judged where it is compared with the study's)."""
    from coopsumo.studies.engine.run_checks import most_lane_changes

    try:
        return most_lane_changes(departed, steps * float(control["dt_s"]), {"control": control})
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return math.inf


def _last_world_steps(config: dict[str, Any]) -> int | None:
    """The steps of a training's last world by its configuration (sim.steps, or its last episode's:
    episodes.episode_bounds), or None when the configuration cannot be read."""
    from coopsumo.agents.episodes import episode_bounds
    from coopsumo.config import train_config_from_dict

    try:
        cfg = train_config_from_dict(config)
    except Exception:  # not a training's configuration: the caller compared it with the study's
        return None
    _, first, end = episode_bounds(cfg.sim.steps, cfg.dqn, cfg.sim.steps - 1)
    return end - first


def model_folder_problem(folder: Path) -> str | None:
    """Why the training folder's model.pt cannot be reused, or None: the training finished (train's marker lists
    its files; written before markers: train_summary.json is there) and the model loads (model_file.load_model)."""
    from coopsumo.agents.model_file import ModelFileError, load_model
    from coopsumo.run_dirs import RUN_MARKER, finished_run

    if (folder / RUN_MARKER).exists():
        if not finished_run(folder, "train"):
            return "is from a training that has not finished"
    elif not (folder / "train_summary.json").exists():
        return "has no train_summary.json (its training has not finished)"
    try:
        _, meta = load_model(folder / "model.pt")
    except ModelFileError as err:
        return f"cannot be used: {err}"
    try:
        recorded = read_json(folder / "config.json")["config"]
    except (OSError, ValueError, KeyError, TypeError):
        return None  # nothing to compare with (the caller checked config.json against the study's configuration)
    if (where := first_difference(meta.get("config"), recorded)) is not None:
        return f"holds a model.pt made by another configuration than its config.json ({where}): swapped?"
    return None
