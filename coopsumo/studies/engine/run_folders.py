"""A study's run folders: a run of one configuration into its folder, the roots studies write, and when a
finished run folder can be reused (its configuration, its outputs, its values)."""

from __future__ import annotations

import dataclasses
import fnmatch
import hashlib
import json
import os
import sys
from collections.abc import Iterable, Sequence
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

from coopsumo.config import ROAD_LENGTH_M, OutputConfig, results_view, to_dict
from coopsumo.files import TEMPORARY, file_sha256, left_temporaries, not_regular, read_json
from coopsumo.record_schemas import SPEED_MAX_MPS
from coopsumo.run_dirs import LEARNERS, RUN_OUTPUTS, Recorded, check_out_path, check_run_dir, check_study_place
from coopsumo.run_dirs import study_root as claim_study_root
from coopsumo.run_markers import RUN_MARKER, changed_file, kind_name
from coopsumo.studies.engine.records import summary_problem
from coopsumo.studies.engine.run_checks import detectors_problem, fcd_problem, run_summary_problem, tripinfo_problem


def same_config(path: Path, cfg: dict[str, Any]) -> bool:
    """True when path (a run or training folder's config.json) records this configuration (config.results_view)."""
    try:
        return bool(results_view(read_json(path)["config"]) == results_view(json.loads(json.dumps(cfg))))
    except (OSError, ValueError, KeyError):
        return False


def check_run_places(folders: Iterable[Path], in_place: bool = False) -> None:
    """UsageError naming the first of a study's run folders still to run that the study may not replace (a user's
    folder, another command's run: run_dirs.check_run_dir: missing, empty, or simulate's and nothing added), before
    any cell runs rather than in its worker (issue 82, probe 7, I10: the protocol refused it per cell). in_place: the
    study writes its runs in place, unmarked (scenario II's evals/ and mobil/), so a folder with no marker holding
    only the names a run writes (RUN_OUTPUTS) is its own (probe 7, I1)."""
    for folder in folders:
        out = folder.resolve()
        if not (in_place and _written_in_place(out)):
            check_run_dir(out, "simulate")


RUN_FILES = tuple(pattern for pattern in RUN_OUTPUTS if not pattern.endswith(TEMPORARY))
"""the files a run writes, their temporaries aside"""


def _written_in_place(out: Path) -> bool:
    """True when `out` is a folder without a marker holding only files a run writes, and the temporaries a killed
    write left of them ('.NAME.XXXXXXXX.tmp': files.left_temporaries): a user's `.notes.tmp` is not one (issue 82,
    probe 10, L2: it was deleted)."""
    if not out.is_dir() or os.path.lexists(out / RUN_MARKER) or out.is_symlink():
        return False
    left = set(left_temporaries(out, RUN_FILES))
    return all(p.is_file() and (p in left or any(fnmatch.fnmatchcase(p.name, pat) for pat in RUN_FILES))
               for p in out.iterdir())  # fmt: skip


def fresh_in_place(out: Path) -> None:
    """Make the folder `out` for a run written in place, unlinking the files an earlier run left in it that have
    another hard link (the names RUN_OUTPUTS lists; check_run_places refused anything else), so that the run writes
    new files rather than through them: SUMO and the trajectory writer open their outputs in place, which changed a
    hard-linked snapshot of the folder (`cp -al`, `rsync --link-dest`; issue 82, probe 9, K7). A file with no other
    link is left to be written again, or kept when the run does not write it (probe 10, L2: a user's fcd.xml in a
    run that writes none was deleted). The temporaries a killed write left of the run's own files ('.NAME.XXXXXXXX.tmp':
    check_run_places took them as the run's) are removed: a rerun of the cell left them in its finished folder."""
    out.mkdir(parents=True, exist_ok=True)
    for left in left_temporaries(out, RUN_FILES):
        left.unlink(missing_ok=True)
    for p in out.iterdir():
        if (p.is_file() and not p.is_symlink() and p.stat().st_nlink > 1
                and any(fnmatch.fnmatchcase(p.name, pat) for pat in RUN_OUTPUTS)):  # fmt: skip
            p.unlink()


def run_places(folder: Path, nested: bool = False) -> list[Path]:
    """`folder`, or (nested) each entry of it: a cell's evaluations, a run folder each (check_run_places)."""
    return sorted(folder.iterdir()) if nested and folder.is_dir() and not folder.is_symlink() else [folder]


RUN_SUMMARY = ("departed", "mean_speed_mps", "throughput_veh_per_h", "lane_changes", "collisions", "teleports")
"""summary.json values a stored accident run must hold as finite numbers to be reused (scenario I's measures)"""


def reusable_run(out: Path, cfg: dict[str, Any], outputs: OutputConfig, model: Path | None = None,
                 prog: str = "scenario1") -> bool:
    """True when the run folder out holds a finished run of the SimConfig dict cfg with the SUMO output files
    `outputs` asks for and, for a model's run, was driven by the model file as it is now (model_driven), and its
    values and files can be trusted (run_folder_problem). A folder that holds a summary.json and is not reused
    gets one line on stderr (of the command `prog`) saying why; UsageError when it is not the study's to run again
    (run_dirs.check_run_dir: a marker with no list of the run's files, a file added to it)."""
    if not (out / "summary.json").exists():
        return False
    if problem := reuse_problem(out, cfg, outputs, model):
        check_run_dir(out.resolve(), "simulate")
        print(f"{prog}: run folder {out} {problem}; running it again", file=sys.stderr)
        return False
    return True


def reuse_problem(out: Path, cfg: dict[str, Any], outputs: OutputConfig, model: Path | None = None) -> str | None:
    """Why the finished run folder out (it holds a summary.json) cannot stand for a run of cfg with `outputs`
    driven by `model` as it is now (reusable_run), or None."""
    if not same_config(out / "config.json", cfg):
        return "was run with another or an unreadable configuration (config.json)"
    try:
        written = read_json(out / "config.json")
        recorded = written.get("sumo_outputs")
    except (OSError, ValueError, AttributeError):
        return "has an unreadable config.json"
    if model is not None and not model_driven(out, written, model):
        return f"was driven by another model than {model} holds now (retrained, replaced or missing)"
    if recorded != to_dict(outputs):
        return f"has other SUMO outputs ({json.dumps(recorded)[:80]}) than the study writes"
    files = (["fcd.xml"] if outputs.fcd_period_s > 0 else []) + (["tripinfo.xml"] if outputs.tripinfo else [])
    if missing := [f for f in files if not (out / f).exists()]:
        return f"has no {missing[0]}"
    return run_folder_problem(out, RUN_SUMMARY, cfg, outputs.fcd_period_s)  # its values and files, not only its config


def model_driven(out: Path, written: Any, model: Path) -> bool:
    """True when the run in out (its config.json: written) was driven by the model file as it is now: the file's
    sha256 recorded at the run equals today's (a retrained model, or a link moved to another model, keeps its
    path). A run written before the digest was recorded: made after the model file was last written."""
    if not model.exists():
        return False
    trained_on = written.get("model_trained_on") if isinstance(written, dict) else None
    digest = trained_on.get("model_sha256") if isinstance(trained_on, dict) else None
    if digest is not None:
        return bool(digest == file_sha256(model))
    return (out / "summary.json").stat().st_mtime >= model.stat().st_mtime


def simulate_into(
    config: dict[str, Any],
    out: Path,
    label: str,
    trajectory_every: int = 0,
    outputs: OutputConfig | None = None,
    atomic: bool = False,
) -> dict[str, Any]:
    """Run the SimConfig dict `config` with its own policy into out; the summary without its policy field.

    trajectory_every: also write trajectories, every this many steps (0: none); outputs: SUMO's FCD and
    tripinfo files; atomic: build the folder aside and move it into place when the run has finished, so a
    killed run leaves no half folder.
    """
    from coopsumo.agents.policies import policy_for_run
    from coopsumo.agents.rollout import run
    from coopsumo.config import sim_config_from_dict
    from coopsumo.run_dirs import atomic_run_dir

    cfg = sim_config_from_dict(config)
    policy = policy_for_run(cfg)
    if not atomic:
        fresh_in_place(out)
    with atomic_run_dir(out) if atomic else nullcontext(out) as run_dir:
        summary = run(cfg, policy, run_dir, trajectories=trajectory_every > 0, progress=False, label=label,
                      trajectory_every=max(trajectory_every, 1), outputs=outputs)  # fmt: skip
    return {k: v for k, v in summary.items() if k != "policy"}


STUDY_OUTPUTS: dict[str, tuple[str, ...]] = {
    "scenario1": ("plan.json", "cells", "models", "runs", "runs.csv", "summary.csv", "report.md", "fig*.png",
                  "gui_jam.png", "gui_jam.json", "claim_a.md"),
    "scenario2": ("sweep.json", "cells", "train", "evals", "mobil", "baselines", "runs.csv", "evals.csv",
                  "alpha_star.csv", "mobil_p_star.csv", "gate.csv", "check.csv", "response.csv", "fig6_*.png",
                  "report.md"),
    "ablation": ("study.json", "cells", "train", "evals", "baselines", "runs.csv", "summary.csv", "fig_*.png",
                 "report.md", "accident"),
    "regime_map": ("plan.json", "cells", "runs", "runs.csv", "report.md"),
    "protocol": ("study.json", "cells", "train", "runs", "runs.csv", "stats.csv", "diagnosis.csv", "fig_*.png",
                 "report.md"),
}  # fmt: skip
"""the names each study writes at the top of its root, its plan file first (run_dirs.check_study_root); `ablation`,
the retired learning study's (its `accident`: the retired accident-seeds' default study in it), so that such a root
is still told from a user's folder"""


def default_out(name: str, profile: str, committed: str) -> Path:
    """A study's results folder when --out is not given: results/<name> for the profile whose report is committed,
    results/<name>_<profile> for any other, so that a quick or test run never replaces a committed report."""
    return Path("results") / (name if profile == committed else f"{name}_{profile}")


def study_root(root: Path, kind: str, study: str | None = None, recorded: Recorded | None = None,
               advice: str = "pick another --out", trains: bool = False,
               profile: Any = None) -> AbstractContextManager[Path]:  # fmt: skip
    """Claim the study root for the block (run_dirs.study_root: path checked, lock held, ownership checked, marked):
    with `study` (profile_study), a root that holds another study of `kind` is refused, with `advice`; `recorded`
    reads which one a root holds whose marker does not say (recorded_profile); `profile`, the profile as its file
    gives it, defines the study too (profile_digest: a root marked with another's settings is refused). trains: the
    study stores models, so its model store is checked first (model_store.store_for), before anything is written; the
    root's place before that (run_dirs.check_study_place: not in another run's or study's folder, nor in the model
    store)."""
    if trains:
        from coopsumo.studies.engine.model_store import store_for

        check_out_path(root)
        check_study_place(root)
        store_for(root)
    digest = profile_digest(profile) if profile is not None else None
    return claim_study_root(root, kind, (*STUDY_OUTPUTS[kind], "*.tmp"), study, recorded, advice, digest=digest)


def profile_digest(profile: Any) -> str:
    """What defines a profile's study beside its name: the first 16 hex digits of the SHA-256 of its settings (the
    profile dataclass as its file gives them, before the command line's flags, which keep its study), as a study
    root's marker records it (run_markers.DIGEST). Another file's profile of the same name, or the profile edited,
    is another study (issue 82, probe 13, F11: its tables and report replaced a finished study's)."""
    text = json.dumps(dataclasses.asdict(profile), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def profile_study(profile: str, what: str = "study", presets: Sequence[str] = ("default",)) -> str:
    """Which study a profile's run writes, as a study root's marker names it: "the quick profile's study", and with
    learner presets other than the default "the quick profile's study (learner preset paper)": another study."""
    learners = "" if tuple(presets) == ("default",) else f"{LEARNERS}{'s' * (len(presets) > 1)} {', '.join(presets)})"
    return f"the {profile} profile's {what}{learners}"


def _at(data: Any, keys: Sequence[str]) -> Any:
    for key in keys:
        data = data[key]
    return data


STUDY_SIGNS: dict[str, tuple[str, ...]] = {"ablation": ("default_learner",), "protocol": ("profile", "t_ups")}
"""where each study that writes study.json (learning: kind ablation, protocol) holds a field the other's lacks: which
command's study a root without a marker holds (issue 82, probe 7, I4: a profile name alone took a protocol study for
a learning study of the same name, and the other way round)"""


def _holds(data: Any, keys: Sequence[str]) -> bool:
    try:
        _at(data, keys)
    except (KeyError, TypeError, IndexError):
        return False
    return True


def recorded_profile(plan_file: str, *keys: str, presets: Sequence[str] = (), kind: str | None = None) -> Recorded:
    """recorded(root) -> profile_study of the profile name a study's plan file holds under `keys` (plan.json's
    plan.profile) and of the learner presets it holds under `presets` (none given or none there: the default), or
    None when there is none or it cannot be read: which study a root written before its marker named it holds. kind:
    a study of STUDY_SIGNS, whose plan file must hold its sign: one holding another's is that command's study."""

    def recorded(root: Path) -> str | None:
        try:
            data = read_json(root / plan_file)
            value = _at(data, keys)
        except (OSError, ValueError, KeyError, TypeError):
            return None
        if kind is not None and not _holds(data, STUDY_SIGNS[kind]):
            other = next((k for k, sign in STUDY_SIGNS.items() if _holds(data, sign)), None)
            return f"a coopsumo {kind_name(other)} study ({plan_file} says so)" if other is not None else None
        try:
            learners = _at(data, presets) if presets else ["default"]
        except (KeyError, TypeError):  # a plan written before its study had learner presets: the default's
            learners = ["default"]
        learners = [learners] if isinstance(learners, str) else learners
        if not isinstance(value, str) or not isinstance(learners, list) or not learners \
                or not all(isinstance(x, str) for x in learners):  # fmt: skip
            return None
        return profile_study(value, presets=learners)

    return recorded


def _listed_but_gone(out: Path) -> str | None:
    """The first entry a finished simulate marker of `out` lists that is not there, or None."""
    from coopsumo.run_dirs import RUN_MARKER, listed_files

    try:
        marker = read_json(out / RUN_MARKER)
    except (OSError, ValueError):
        return None
    listed = listed_files(marker) if isinstance(marker, dict) and marker.get("kind") == "simulate" else None
    return next((name for name in listed or () if not (out / name).exists()), None)


TRAJECTORY_LIMITS = {"speed_mps": (0.0, SPEED_MAX_MPS), "pos_m": (0.0, ROAD_LENGTH_M[1]), "time_s": (0.0, None)}
"""the trajectory columns' physical limits (a lane's: 0 to the road's lanes - 1, from the run's configuration)"""


def trajectories_problem(path: Path, cfg: dict[str, Any]) -> str | None:
    """Why a run's trajectories.parquet holds a sample no run makes, or None: a speed outside 0-70 m/s, a position
    off the longest road, a time before 0, a lane off the run's road."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    lanes = cfg.get("road", {}).get("lanes") if isinstance(cfg.get("road"), dict) else None
    limits = {**TRAJECTORY_LIMITS, "lane": (0, lanes - 1 if isinstance(lanes, int) else None)}
    table = pq.read_table(path, columns=[n for n in pq.read_schema(path).names if n in limits])  # not vid
    for name, (low, high) in limits.items():
        if name not in table.column_names or table.num_rows == 0:
            continue
        ends = pc.min_max(table[name])
        for end in (ends["min"].as_py(), ends["max"].as_py()):
            if end is None or end != end or (low is not None and end < low) or (high is not None and end > high):
                return f"has a trajectory sample with {name} = {end} (outside {low} to {high}) in {path.name}"
    return None


def run_folder_problem(out: Path, required: Sequence[str], cfg: dict[str, Any], fcd_period_s: float) -> str | None:
    """Why a finished run folder of the SimConfig dict cfg (simulate's: config.json, summary.json, detectors.xml,
    maybe fcd.xml every fcd_period_s, tripinfo.xml, trajectories.parquet) cannot be reused as it is, or None: marked
    finished by simulate (or written before markers: no marker at all), its summary trusted (summary_problem) and
    consistent with itself and cfg (run_checks.run_summary_problem), detectors.xml, fcd.xml and tripinfo.xml
    complete and consistent with it (run_checks), trajectories.parquet readable."""
    import pyarrow.parquet as pq

    from coopsumo.run_dirs import RUN_MARKER, finished_run

    if (out / RUN_MARKER).exists() and not finished_run(out, "simulate"):
        if gone := _listed_but_gone(out):  # the marker is fine: one of the files it lists was deleted
            return f"has lost {gone}, which its {RUN_MARKER} lists"
        return f"has a {RUN_MARKER} that does not mark a finished simulate run"
    if problem := summary_problem(out / "summary.json", required):
        return problem
    summary = read_json(out / "summary.json")  # summary_problem read it: a JSON object
    if problem := run_summary_problem(summary, cfg):
        return problem
    sim_seconds, dt = float(summary["sim_seconds"]), float(cfg["control"]["dt_s"])
    if problem := detectors_problem(out / "detectors.xml", cfg, sim_seconds):
        return problem
    if (out / "fcd.xml").exists() and (problem := fcd_problem(out / "fcd.xml", sim_seconds, fcd_period_s, dt)):
        return problem
    if (out / "tripinfo.xml").exists() and (problem := tripinfo_problem(out / "tripinfo.xml", summary)):
        return problem
    if (out / "trajectories.parquet").exists():
        if (kind := not_regular(out / "trajectories.parquet")) is not None:  # pyarrow would wait on a named pipe
            return f"has a trajectories.parquet that is not a regular file but {kind}"
        try:
            pq.read_metadata(out / "trajectories.parquet")
        except Exception:  # pyarrow raises several types for a damaged file
            return "has an unreadable trajectories.parquet"
        if problem := trajectories_problem(out / "trajectories.parquet", cfg):
            return problem
    return changed_file(out)  # last: a file each check above takes, but another run's (issue 82, probe 16, TR1)
