"""`coopsumo history`: the learner search's table is generated from the protocol studies' own records, the committed
table is what the command prints today, and it writes only with --out, over nothing but a table it wrote (issue 82: it
overwrote a user's file)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest
from conftest import main_here

from coopsumo.config import to_dict
from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.errors import UsageError
from coopsumo.studies.protocol import history

ROOT = Path(__file__).resolve().parent.parent
COMMITTED = ROOT / "results" / "history" / "README.md"
KEEP_OUT = ("date", "commit")
"""columns that come from git (a shallow clone may lack them): left out of the comparison with the committed table"""


def _columns(text: str) -> list[dict[str, str]]:
    lines = [line for line in text.splitlines() if line.startswith("| ")]
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = [dict(zip(head, (c.strip() for c in line.strip("|").split("|")), strict=True)) for line in lines[1:]]
    return [{k: v for k, v in row.items() if k not in KEEP_OUT} for row in rows]


def _history(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "coopsumo", "history", *args], cwd=cwd, capture_output=True,
                          text=True, check=False)  # fmt: skip


def _history_here(args: list[str], cwd: Path, monkeypatch: pytest.MonkeyPatch,
                  capsys: pytest.CaptureFixture[str]) -> subprocess.CompletedProcess[str]:  # fmt: skip
    """_history's command by history's main in this process, in cwd, for the refusals after a test's first, which runs
    as a process (a process each: about half a second of the suite's time per refusal)."""
    with monkeypatch.context() as patch:
        patch.chdir(cwd)
        code, out, err = main_here(history.main, args, capsys)
    return subprocess.CompletedProcess(["history", *args], code, out, err)


def test_committed_table_is_what_the_command_prints() -> None:
    before = COMMITTED.stat().st_mtime_ns, COMMITTED.read_bytes()
    res = _history()
    assert res.returncode == 0, res.stderr
    assert (COMMITTED.stat().st_mtime_ns, COMMITTED.read_bytes()) == before  # printed, not written

    def rows(text: str) -> list[list[str]]:  # the order follows git's dates: a shallow clone may order otherwise
        return sorted(list(row.values()) for row in _columns(text))

    assert rows(res.stdout) == rows(COMMITTED.read_text()), ("results/history/README.md: run coopsumo history --out "
                                                              "results/history/README.md")  # fmt: skip
    studies = history.study_folders(ROOT / "results")
    assert len(studies) >= 20 and all(f"]({history._link(s, ROOT / 'results')})" in res.stdout for s in studies)
    assert res.stdout.splitlines()[0] == history.TITLE and res.stdout.splitlines()[2].startswith(history.GENERATED)
    history.check_writable(COMMITTED)  # `--out results/history/README.md` may rewrite it: a table it wrote


def _study(folder: Path, learner: dict, drive: dict, rows: list[dict]) -> None:
    folder.mkdir(parents=True)
    (folder / "study.json").write_text(json.dumps({"profile": {"eval_offsets": [0, 20]},
                                                   "learners": {"v": {"learner": learner, "drive": drive,
                                                                      "weights": "model.pt"}}}))  # fmt: skip
    pd.DataFrame(rows).to_csv(folder / "stats.csv", index=False)


def _row(scenario: str, t_up: float, iqm: float, keep: float, keep_low: float) -> dict:
    return {"scenario": scenario, "t_up": t_up, "variant": "v", "models": 5, "iqm": iqm, "low": iqm, "high": iqm,
            "worst": iqm, "mean": iqm, "lane_changes_per_vehicle": 1.0, "keep_value": keep, "keep_poi": keep_low,
            "keep_poi_low": keep_low, "keep_poi_high": 1.0, "greedy_poi": 0.6, "mobil:p=0_poi": 0.4}  # fmt: skip


def test_a_row_reads_the_records(tmp_path: Path) -> None:
    learner = json.loads(json.dumps(to_dict(DQN_PRESETS["default"])))
    learner["gamma"] = 0.95
    _study(tmp_path / "history" / "learner_protocol_x", learner, {"change_margin": 2.0},
           [_row("free", 2.0, 20.0, 18.0, 0.9), _row("free", 1.0, 17.0, 16.5, 0.3),
            _row("accident", 2.0, 30.0, 31.5, 0.8)])  # fmt: skip
    text = history.table(tmp_path)
    row = _columns(text)[0]
    assert row["differs from today's default"] == "gamma 0.95; drives with change_margin 2"
    assert row["models x evaluation sets"] == "5 x 2" and row["T_up (s)"] == "2 / 1"
    assert row["free flow: IQM - keep (m/s)"] == "+2.00 / +0.50"
    assert row["accident: IQM - keep (veh-h)"] == "-1.5"
    assert row["verdict"] == "free flow: ahead of keep at 1 of 2; accident: ahead of keep at 1 of 1"
    assert row["report"] == "[learner_protocol_x](learner_protocol_x/report.md)"


def test_an_old_record_without_a_later_field_means_its_implied_value(tmp_path: Path) -> None:
    learner = json.loads(json.dumps(to_dict(DQN_PRESETS["default"])))
    del learner["no_return_s"]  # recorded before the field existed: no such rule
    assert history.differences(learner, {}, "model_last.pt") == "no_return_s 0; weights model_last.pt"


def test_no_study_is_one_line_and_exit_code_2(tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "coopsumo", "history", "--results", str(tmp_path)], cwd=tmp_path,
                         capture_output=True, text=True, check=False)  # fmt: skip
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "no learner protocol" in res.stderr
    assert not any(tmp_path.iterdir())
    res = subprocess.run([sys.executable, "-m", "coopsumo", "history", "--results", str(tmp_path / "none")],
                         cwd=tmp_path, capture_output=True, text=True, check=False)  # fmt: skip
    assert res.returncode == 2 and "no such folder" in res.stderr
    (tmp_path / "notes.md").write_text("x")  # issue 82 (h2): a file was called no such folder
    res = subprocess.run([sys.executable, "-m", "coopsumo", "history", "--results", str(tmp_path / "notes.md")],
                         cwd=tmp_path, capture_output=True, text=True, check=False)  # fmt: skip
    assert res.returncode == 2 and f"--results {tmp_path / 'notes.md'}: not a folder" in res.stderr, res.stderr


def test_an_empty_results_is_refused_not_read_as_the_working_folder(tmp_path: Path) -> None:
    """Issue 82 (probe 3, F12): `--results ""` read the working folder, here one holding a study."""
    _one_study(tmp_path)
    before = _files(tmp_path)
    res = _history("--results", "", "--out", str(tmp_path / "table.md"), cwd=tmp_path)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and "--results: is empty" in lines[0], res.stderr
    assert res.stdout == "" and _files(tmp_path) == before


def test_a_frozen_study_is_found_where_it_was_moved(tmp_path: Path) -> None:
    from coopsumo.studies.protocol.report import committed_folder

    shutil.copytree(ROOT / "results" / "history" / "learner_protocol_f05q_ts2k10", tmp_path / "history" / "f")
    assert committed_folder(tmp_path, "f") == tmp_path / "history" / "f"
    (tmp_path / "f").mkdir()
    assert committed_folder(tmp_path, "f") == tmp_path / "f"


def test_a_study_folder_linked_from_elsewhere_is_linked_where_its_link_is(tmp_path: Path) -> None:
    """Issue 82, probe 12, N9: a study folder in the results folder that is a link to a study outside it was a
    traceback (its place taken from where the link leads); its row links it at the link's own name."""
    _one_study(tmp_path / "outside", gamma=0.8)
    results = tmp_path / "results"
    _one_study(results)
    (results / "learner_protocol_link").symlink_to(tmp_path / "outside" / "learner_protocol_g0.8")
    (results / "history").mkdir()
    (results / "history" / "learner_protocol_back").symlink_to(Path("../../outside/learner_protocol_g0.8"))
    res = _history("--results", "results", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    links = {"learner_protocol_back": "learner_protocol_back", "learner_protocol_g0.95": "../learner_protocol_g0.95"}
    assert sorted(row["report"] for row in _columns(res.stdout)) == [f"[{k}]({v}/report.md)" for k, v in links.items()]
    # the second link to the same study is that study, listed once (probe 20, TR2)
    assert res.stderr.strip().endswith("learner_protocol_link is the study of results/history/learner_protocol_back "
                                       "(a link to it or a copy of it): listed once"), res.stderr  # fmt: skip


def _one_study(results: Path, gamma: float = 0.95) -> None:
    learner = json.loads(json.dumps(to_dict(DQN_PRESETS["default"])))
    learner["gamma"] = gamma
    _study(results / f"learner_protocol_g{gamma:g}", learner, {}, [_row("free", 2.0, 20.0, 18.0, 0.9)])


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_without_out_the_table_is_printed_and_nothing_written(tmp_path: Path) -> None:
    results = tmp_path / "results"
    _one_study(results)
    before = _files(tmp_path)
    res = _history("--results", str(results), cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout == history.table(results) and _files(tmp_path) == before
    assert not (results / "history").exists()


def test_out_writes_a_new_file_then_only_its_own_table(tmp_path: Path) -> None:
    results = tmp_path / "results"
    _one_study(results)
    out = tmp_path / "tables" / "history.md"
    res = _history("--results", str(results), "--out", str(out), cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout == f"history: 1 learners judged, written to {out}\n" and out.read_text() == history.table(results)
    _one_study(results, gamma=0.8)  # a second study: the table it wrote is rewritten whole
    res = _history("--results", str(results), "--out", str(out), cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert out.read_text() == history.table(results) and len(_columns(out.read_text())) == 2


def test_out_refuses_a_file_it_did_not_write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The first refusal as a process, as a user meets it; the others by history's main in this process."""
    results = tmp_path / "results"
    _one_study(results)
    mine = history.table(results).splitlines()
    others = {
        "notes.md": "my notes\n",
        "empty.md": "",
        "title_only.md": f"{history.TITLE}\n\nmy own page under the same title\n",
        "binary.md": b"\xff\xfe\x00".decode("latin-1"),
        "edited.md": "\n".join(["# My table", *mine[1:]]) + "\n",
    }
    for name, text in others.items():
        (tmp_path / name).write_text(text, encoding="latin-1")
    (tmp_path / "folder.md").mkdir()
    before = _files(tmp_path)
    for i, name in enumerate([*others, "folder.md"]):
        args = ["--results", str(results), "--out", str(tmp_path / name)]
        res = _history(*args, cwd=tmp_path) if i == 0 else _history_here(args, tmp_path, monkeypatch, capsys)
        assert res.returncode == 2 and res.stdout == "", name
        assert len(res.stderr.strip().splitlines()) == 1 and f"--out {tmp_path / name}" in res.stderr, res.stderr
        assert "Traceback" not in res.stderr
    assert _files(tmp_path) == before and (tmp_path / "folder.md").is_dir()


def test_out_refuses_its_own_table_with_a_users_text_around_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 13, F12: a table it wrote with a user's notes appended below it was overwritten, exit 0 (only
    its first 3 lines were checked); the whole file must be what it writes. The first refusal as a process, the others
    by history's main in this process."""
    results = tmp_path / "results"
    _one_study(results)
    mine = history.table(results)
    lines = mine.splitlines()
    others = {
        "appended.md": mine + "MY NOTES: keep me\n",
        "appended_no_newline.md": mine + "MY NOTES",
        "blank_then_notes.md": mine + "\nMY NOTES\n",
        "inserted_row.md": "\n".join([*lines[:6], "| my own row |", *lines[6:]]) + "\n",
        "note_between.md": "\n".join([*lines[:4], "a note", *lines[4:]]) + "\n",
        "no_rows.md": "\n".join(lines[:6]) + "\n",
        "cut_last_newline.md": mine[:-1],
        # probe 14, F5: the shape kept, the user's text inside it
        "note_in_generated_line.md": mine.replace(lines[2], lines[2] + " MY NOTE: keep me"),
        "note_in_a_row.md": mine.replace(lines[6], lines[6].replace("` |", "` (MY NOTE) |", 1)),
        "row_added.md": mine.replace(lines[6], lines[6] + "\n| `mine` | MY NOTE | [r](x/report.md) |"),
        "unsealed.md": mine[: mine.rfind(history.SEAL)],
    }
    for name, text in others.items():
        (tmp_path / name).write_text(text)
    before = _files(tmp_path)
    for i, name in enumerate(others):
        args = ["--results", str(results), "--out", str(tmp_path / name)]
        res = _history(*args, cwd=tmp_path) if i == 0 else _history_here(args, tmp_path, monkeypatch, capsys)
        assert res.returncode == 2 and res.stdout == "", (name, res.stderr)
        assert len(res.stderr.strip().splitlines()) == 1 and "not a table coopsumo history wrote" in res.stderr
    assert _files(tmp_path) == before
    assert history.is_own_table(mine) and history.is_own_table(COMMITTED.read_text())


def test_out_never_writes_through_a_file_or_link_named_like_its_temporary(tmp_path: Path) -> None:
    """Issue 82, F24: the table was written through 'FILE.tmp': a link of that name had its target overwritten, a
    user's file of that name was renamed onto FILE."""
    results = tmp_path / "results"
    _one_study(results)
    (tmp_path / "user").mkdir()
    (tmp_path / "user" / "important.txt").write_text("precious\n")
    (tmp_path / "table.md.tmp").symlink_to(tmp_path / "user" / "important.txt")
    (tmp_path / "t2.md.tmp").write_text("my draft\n")
    for name in ("table.md", "t2.md"):
        res = _history("--results", str(results), "--out", str(tmp_path / name), cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert (tmp_path / name).read_text() == history.table(results) and not (tmp_path / name).is_symlink()
    assert (tmp_path / "user" / "important.txt").read_text() == "precious\n"
    assert (tmp_path / "table.md.tmp").is_symlink() and (tmp_path / "t2.md.tmp").read_text() == "my draft\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results", "t2.md", "t2.md.tmp", "table.md", "table.md.tmp",
                                                          "user"]  # fmt: skip


def _stats(change: dict) -> Callable[[Path], object]:
    """A change to the first row of a study's stats.csv (None: drop the column)."""

    def spoil(folder: Path) -> None:
        table = pd.read_csv(folder / "stats.csv")
        for column, value in change.items():
            if value is None:
                table = table.drop(columns=column)
            else:
                table[column] = table[column].astype(object)
                table.loc[0, column] = value
        table.to_csv(folder / "stats.csv", index=False)

    return spoil


def _text(name: str, text: str) -> Callable[[Path], object]:
    return lambda folder: (folder / name).write_text(text)


def _learners(value: object) -> Callable[[Path], object]:
    def spoil(folder: Path) -> None:
        study = json.loads((folder / "study.json").read_text())
        study["learners"] = value
        (folder / "study.json").write_text(json.dumps(study))

    return spoil


def _profile_and_stats(profile: dict, change: dict) -> Callable[[Path], object]:
    """study.json's profile given `profile`'s fields, and the change to stats.csv's first row (_stats)."""

    def spoil(folder: Path) -> None:
        study = json.loads((folder / "study.json").read_text())
        study["profile"].update(profile)
        (folder / "study.json").write_text(json.dumps(study))
        _stats(change)(folder)

    return spoil


def _stats_of_another_learner(folder: Path) -> None:
    table = pd.read_csv(folder / "stats.csv")
    table["variant"] = "w"
    table.to_csv(folder / "stats.csv", index=False)


def _row_twice(folder: Path) -> None:
    table = pd.read_csv(folder / "stats.csv")
    first = table.iloc[[0]].copy()
    first["iqm"] = first["iqm"] + 1.0  # the second copy says otherwise
    pd.concat([table.iloc[[0]], first, table.iloc[1:]]).to_csv(folder / "stats.csv", index=False)


SPOILED = {
    # the probe's (2026-12-01): tracebacks (h5-h9), and numbers copied into the table (h20, h21)
    "study.json not JSON": (_text("study.json", "{not json"), "study.json cannot be read as JSON (JSONDecodeError)"),
    "stats.csv without iqm": (_stats({"iqm": None}), "stats.csv has no column iqm"),
    "stats.csv empty": (_text("stats.csv", ""), "stats.csv cannot be read as a table (EmptyDataError)"),
    "study.json a list": (_text("study.json", "[1, 2]"), "study.json is not a JSON object (got list)"),
    "a learner not a table": (_learners({"v": 3}), "study.json field learners.v must be a mapping, got 3"),
    "keep's value nan": (_stats({"keep_value": "nan"}), "stats.csv row 1 column keep_value must be a finite number"),
    "an IQM of 1e9 m/s": (_stats({"iqm": 1e9}), "stats.csv row 1 column iqm must be a finite number >= 0 and <= 70 "
                          "(m/s), got 1000000000.0"),
    # the other fields of record_schemas.PROTOCOL_STUDY and PROTOCOL_STATS
    "learners a list": (_learners([1]), "study.json field learners must be a mapping"),
    "no learners": (_text("study.json", "{}"), "study.json has no field learners"),
    "a speed below 0": (_stats({"low": -1.0}), "row 1 column low must be"),
    "worst a word": (_stats({"worst": "x"}), "row 1 column worst must be a number (m/s), got 'x'"),
    "a probability of 1.5": (_stats({"keep_poi_high": 1.5}), "row 1 column keep_poi_high must be a finite number >= 0 "
                             "and <= 1 (a probability)"),
    "greedy's probability nan": (_stats({"greedy_poi": "nan"}), "row 1 column greedy_poi"),
    "a negative count of losses": (_stats({"keep_losses": -1}), "row 1 column keep_losses must be an integer >= 0"),
    "2.5 models": (_stats({"models": 2.5}), "row 1 column models must be an integer"),
    "another scenario": (_stats({"scenario": "jam"}), "row 1 column scenario must be one of free, accident"),
    "a demand of 0 s": (_stats({"t_up": 0.0}), "row 1 column t_up must be"),
    "lane changes 1e6": (_stats({"lane_changes_per_vehicle": 1e6}), "row 1 column lane_changes_per_vehicle"),
    "no greedy column": (_stats({"greedy_poi": None}), "stats.csv has no column greedy_poi"),
    # issue 82 (2026-12-02): a row given twice was copied into the table
    "a row given twice": (_row_twice, "stats.csv rows 1 and 2 are both the row of scenario 'free', t_up 2.0, variant"),
    # issue 82 (h19): a study was called 'no learner protocol study ... here'
    "no rows for its learner": (_stats_of_another_learner, "stats.csv has no free-flow rows for learner v"),
    # issue 82 (2026-12-02): a row of a learner study.json does not name was dropped; a learner's settings no learner
    # takes were printed into the table
    "a row of another learner": (lambda f: pd.concat([pd.read_csv(f / "stats.csv"), pd.read_csv(f / "stats.csv").iloc[
                                     [0]].assign(variant="zzz")]).to_csv(f / "stats.csv", index=False),
                                 "stats.csv has rows of learner zzz, which study.json does not name"),
    "a learning rate of -1": (_learners({"v": {"learner": {**to_dict(DQN_PRESETS["default"]), "lr": -1.0}}}),
                              "study.json learner v has settings no learner takes: lr must be a finite number > 0"),
    "preset 5": (_learners({"v": {"learner": {**to_dict(DQN_PRESETS["default"]), "preset": 5}}}),
                 "study.json learner v has settings no learner takes: preset must be a string, got 5"),
    # issue 82 (probe 3, F11): drive settings no policy takes were printed ("drives with margin -5"); a learner gone
    # from study.json, its rows left in stats.csv, is named
    "a drive setting no policy has": (_learners({"v": {"drive": {"margin": -5}}}),
                                      "study.json learner v drives with margin, a setting no policy takes"),
    "a change margin of -5": (_learners({"v": {"drive": {"change_margin": -5}}}), "study.json learner v drives with "
                              "change_margin -5, which no policy takes: it must be a finite number >= 0 and <= 100"),
    "a cooldown of 1e9 s": (_learners({"v": {"drive": {"change_cooldown_s": 1e9}}}),
                            "drives with change_cooldown_s 1e+09, which no policy takes: it must be"),
    "a cooldown as text": (_learners({"v": {"drive": {"change_cooldown_s": "10"}}}),
                           "drives with change_cooldown_s '10', which no policy takes: it must be a finite number"),
    "an ensemble of 2.5": (_learners({"v": {"drive": {"ensemble_snapshots": 2.5}}}),
                           "drives with ensemble_snapshots 2.5, which no policy takes: it must be a whole number"),
    "its learner gone from study.json": (_learners({}),
                                         "stats.csv has rows of learner v, which study.json does not name"),
    # issue 82, probe 8, J12: each value inside its limits, the row none its study made
    "an IQM far outside its interval": (_stats({"iqm": 25.0, "low": 20.25, "high": 20.8, "worst": 20.0}),
                                        "row 1 (free, v) has iqm 25 far outside its interval 20.25-20.8"),
    "low above high": (_stats({"low": 21.0, "high": 19.0}), "row 1 (free, v) has low 21 above high 19"),
    "a worst model better than the IQM": (_stats({"worst": 30.0}), "row 1 (free, v) has worst 30 better than its iqm"),
    "50 models of 10 seeds": (_profile_and_stats({"seeds": list(range(10)), "t_ups": [2.0]}, {"models": 50}),
                              "row 1 (free, v) has 50 models, more than its study's 20"),
    "a demand the study did not run": (_profile_and_stats({"seeds": list(range(10)), "t_ups": [1.0]}, {}),
                                       "row 1 (free, v) has t_up 2, a demand its study did not run"),
    # probe 9: the profile's lists that check reads, of the wrong types, were tracebacks
    "t_ups a text": (_profile_and_stats({"t_ups": "abc"}, {}), "whose profile.t_ups is abc, not a list of numbers"),
    "seeds a number": (_profile_and_stats({"seeds": 10}, {}), "whose profile.seeds is 10, not a list of numbers"),
    "t_ups nested": (_profile_and_stats({"t_ups": [[2.0]]}, {}), "profile.t_ups is [[2.0]], not a list of numbers"),
    "t_ups null": (_profile_and_stats({"t_ups": None}, {}), "profile.t_ups is None, not a list of numbers"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(SPOILED))
def test_a_spoiled_record_is_one_line_and_nothing_is_written(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spoil, fragment = SPOILED[case]
    folder = tmp_path / "results" / "learner_protocol_x"
    learner = json.loads(json.dumps(to_dict(DQN_PRESETS["default"])))
    _study(folder, learner, {}, [_row("free", 2.0, 20.0, 18.0, 0.9) | {"keep_losses": 0},
                                 _row("accident", 2.0, 30.0, 31.5, 0.8) | {"keep_losses": 1}])  # fmt: skip
    assert history.main(["--results", str(tmp_path / "results")]) == 0  # the study before it is spoiled
    capsys.readouterr()
    spoil(folder)
    out = tmp_path / "table.md"
    code = history.main(["--results", str(tmp_path / "results"), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith(f"history: error: {folder}/") and fragment in err, (fragment, err)
    assert not out.exists()


def test_out_refuses_a_pipe_without_waiting_on_it(tmp_path: Path) -> None:
    """A fresh probe (issue 82): `history --out FIFO` waited for a writer forever; it is refused in one line."""
    import os

    fifo = tmp_path / "table.md"
    os.mkfifo(fifo)
    with pytest.raises(UsageError, match="is not a regular file"):
        history.check_writable(fifo)


def test_out_refuses_a_file_in_a_folder_coopsumo_owns(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """Issue 82, probe 4, F17: `history --out` wrote its table into the model store (every study then refused the
    store), an interrupted training's folder (it could no longer be resumed), a run's or a study's folder. A file
    there is refused as a run's --out there is (owners.owned_problem): one line naming the folder, nothing written."""
    from coopsumo.run_dirs import mark_run_dir

    results = tmp_path / "results"
    _one_study(results)
    study = results / "learner_protocol_g0.95"
    mark_run_dir(study, "protocol", finished=False, study="the tiny profile's study")
    store, env_store = tmp_path / "models", tmp_path / "env_store"
    (store / "default_a0_seed100_0123456789ab").mkdir(parents=True)
    env_store.mkdir()
    monkeypatch.setenv("COOPSUMO_MODELS", str(env_store))
    for name, kind in (("ck", "train"), ("sim", "simulate")):
        (tmp_path / name).mkdir()
        mark_run_dir(tmp_path / name, kind, finished=kind == "simulate")
    before = _files(tmp_path)
    for out, says in ((store / "t.md", "a model store"), (env_store / "t.md", "is in the model store"),
                      (tmp_path / "ck" / "t.md", "the folder of a coopsumo train run"),
                      (tmp_path / "sim" / "t.md", "the folder of a coopsumo simulate run"),
                      (study / "t.md", "a coopsumo protocol study's folder")):  # fmt: skip
        assert history.main(["--results", str(results), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and f"--out {out}" in err and says in err, err
    assert _files(tmp_path) == before


def test_an_interrupted_history_says_so_as_its_early_line_does(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 7, I17a: a Ctrl-C while the table is built is `history: interrupted`, the line a Ctrl-C during
    the imports gives (cli.command_of), not `coopsumo history: interrupted`."""
    from coopsumo.cli import command_of

    def stopped(_results: Path) -> str:
        raise KeyboardInterrupt

    monkeypatch.setattr(history, "table", stopped)
    (tmp_path / "results").mkdir()
    assert history.main(["--results", str(tmp_path / "results")]) == 130
    assert capsys.readouterr().err == f"{command_of(['history'])}: interrupted\n" == "history: interrupted\n"


def test_a_closed_stdout_is_no_traceback(tmp_path: Path) -> None:
    """Issue 82, probe 15, T2: `coopsumo history >&-` (Python's sys.stdout is then None) ended in an AttributeError
    traceback; it prints nothing and ends as `models >&-` does, exit 0, nothing on stderr."""
    results = tmp_path / "results"
    _one_study(results)
    res = subprocess.run(["bash", "-c", f'exec "{sys.executable}" -m coopsumo history --results "{results}" >&-'],
                         cwd=tmp_path, capture_output=True, text=True, check=False)  # fmt: skip
    assert (res.returncode, res.stderr) == (0, ""), res.stderr


def test_a_study_linked_or_copied_is_listed_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 82, probe 20, TR2: a link to a protocol study, or a copy of it, under --results was listed as a second
    study ("4 learners judged" for 2), without a line; now once, the other named in one line."""
    learner = json.loads(json.dumps(to_dict(DQN_PRESETS["default"])))
    study = tmp_path / "history" / "learner_protocol_x"
    _study(study, learner, {}, [_row("free", 2.0, 20.0, 18.0, 0.9)])
    (tmp_path / "learner_protocol_link").symlink_to(study)
    shutil.copytree(study, tmp_path / "learner_protocol_copy")
    capsys.readouterr()
    kept = history.study_folders(tmp_path)  # the first by name of the three: the copy
    assert kept == [tmp_path / "learner_protocol_copy"]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.endswith(f"is the study of {kept[0]} (a link to it or a copy of it): listed once")
                                 for line in err), err  # fmt: skip
    assert len(_columns(history.table(tmp_path))) == 1
