"""Files coopsumo makes beside a user's paths (lock files, partial folders) never follow a link and never replace or
remove what coopsumo did not make (issue 82, probe 4: F1, F2, F3)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from coopsumo import lock_files, simulate
from coopsumo.agents import train_cli as train
from coopsumo.errors import UsageError
from coopsumo.lock_files import ForeignLock, release_lock, try_lock
from coopsumo.run_dirs import PARTIAL_MARKER, lock_path, out_lock

SIM = ["--steps", "20", "--quiet"]


def snapshot(folder: Path) -> dict[str, str]:
    """Every entry under `folder`: a link as where it leads (not followed), a folder as such, a file as its digest."""
    return {str(p.relative_to(folder)): f"-> {p.readlink()}" if p.is_symlink() else "dir" if p.is_dir()
            else hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*"))}  # fmt: skip


def one_line(code: int, err: str, *fragments: str) -> None:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert all(f in lines[0] for f in fragments), (fragments, lines[0])


def _user_file(tmp_path: Path) -> Path:
    (tmp_path / "user").mkdir()
    target = tmp_path / "user" / "important.txt"
    target.write_text("precious\n")
    return target


# -- F1: the lock file beside --out ---------------------------------------------------------------------------------
@pytest.mark.parametrize("command", ["simulate", "train"])
def test_a_link_named_like_the_lock_is_refused_and_its_target_kept(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = _user_file(tmp_path)
    (tmp_path / ".run.lock").symlink_to(target)
    before = snapshot(tmp_path)
    main = simulate.main if command == "simulate" else train.main
    code = main([*SIM, "--out", str(tmp_path / "run")])
    one_line(code, capsys.readouterr().err, str(tmp_path / ".run.lock"), "is a link to", "left alone")
    assert snapshot(tmp_path) == before and target.read_text() == "precious\n"


@pytest.mark.parametrize("text", ["my data\n", "", "simulate, pid\n"])
def test_a_file_named_like_the_lock_that_coopsumo_did_not_write_is_refused_and_kept(
    text: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(lock_files, "EMPTY_WAIT_S", 0.05)
    (tmp_path / ".run.lock").write_text(text)
    before = snapshot(tmp_path)
    code = simulate.main([*SIM, "--out", str(tmp_path / "run")])
    one_line(code, capsys.readouterr().err, str(tmp_path / ".run.lock"), "not a lock file coopsumo made")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("text", ["simulate, pid 1\n", "coopsumo train, pid 99999999\n"])
def test_a_stale_lock_of_coopsumo_is_taken_over_and_removed(text: str, tmp_path: Path) -> None:
    (tmp_path / ".run.lock").write_text(text)  # left by a killed command (older versions wrote no 'coopsumo ')
    assert simulate.main([*SIM, "--out", str(tmp_path / "run")]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_the_lock_file_is_made_new_and_names_its_holder(tmp_path: Path) -> None:
    out = tmp_path / "run"
    with out_lock(out, "simulate"):
        path = lock_path(out.resolve())
        assert path.read_text().startswith("coopsumo simulate, pid ") and not path.is_symlink()
        with pytest.raises(UsageError, match="another coopsumo command is writing"):
            with out_lock(out, "train"):
                pass
    assert list(tmp_path.iterdir()) == []


def test_try_lock_refuses_a_folder_and_a_dangling_link(tmp_path: Path) -> None:
    (tmp_path / ".a.lock").mkdir()
    (tmp_path / ".b.lock").symlink_to(tmp_path / "nowhere")
    for name in (".a.lock", ".b.lock"):
        with pytest.raises(ForeignLock):
            try_lock(tmp_path / name)
    assert not (tmp_path / "nowhere").exists() and (tmp_path / ".a.lock").is_dir()
    fd = try_lock(tmp_path / ".c.lock")
    assert fd is not None
    release_lock(fd, tmp_path / ".c.lock")
    assert sorted(p.name for p in tmp_path.iterdir()) == [".a.lock", ".b.lock"]


# -- F2: what a run clears beside its --out ---------------------------------------------------------------------------
def test_a_run_removes_only_the_partial_folders_and_locks_coopsumo_made(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / ".mydb.lock").write_text("db lock state\n")
    (tmp_path / ".backup.partial-20261203").mkdir()
    (tmp_path / ".backup.partial-20261203" / "chapter1.tex").write_text("thesis\n")
    (tmp_path / ".old.lock").symlink_to(_user_file(tmp_path))
    (tmp_path / ".cut.partial-abcd1234").mkdir()  # left by a killed run
    (tmp_path / ".cut.partial-abcd1234" / PARTIAL_MARKER).write_text("the partial folder of a coopsumo run\n")
    (tmp_path / ".gone.lock").write_text("coopsumo simulate, pid 99999999\n")
    before = snapshot(tmp_path)
    assert simulate.main([*SIM, "--out", str(tmp_path / "run")]) == 0
    after = snapshot(tmp_path)
    kept = {k: v for k, v in before.items() if not k.startswith((".cut.", ".gone."))}
    assert {k: v for k, v in after.items() if k in before} == kept
    assert sorted(set(after) - set(before)) == sorted(k for k in after if k == "run" or k.startswith("run/"))
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and ".cut.partial-abcd1234, the partial folder of an interrupted run" in lines[0], lines
    assert not any(PARTIAL_MARKER in k for k in after if k.startswith("run"))  # the marker stays out of the run


# -- F3: the model store's locks -----------------------------------------------------------------------------------
MODEL = "default_a0_seed100_0123456789ab"


def test_a_link_or_a_file_of_ones_own_named_like_a_models_lock_makes_the_store_refused(tmp_path: Path) -> None:
    from coopsumo.studies.engine.model_store import store_problem

    store = tmp_path / "store"
    (store / MODEL).mkdir(parents=True)
    lock = store / f".{MODEL}.lock"
    assert store_problem(store) is None
    lock.write_text("")  # the store's locks were written empty before issue 82
    assert store_problem(store) is None
    lock.write_text("coopsumo store, pid 99999999\n")
    assert store_problem(store) is None
    lock.write_text("my notes\n")
    assert "holds text of its own" in (store_problem(store) or "")
    lock.unlink()
    lock.symlink_to(_user_file(tmp_path))
    assert "a link to" in (store_problem(store) or "")
    assert (tmp_path / "user" / "important.txt").read_text() == "precious\n"


def test_the_store_lock_never_writes_through_a_link_nor_removes_a_file_of_ones_own(tmp_path: Path) -> None:
    from coopsumo.studies.engine.model_store import _locked

    target = _user_file(tmp_path)
    (tmp_path / ".a.lock").symlink_to(target)
    (tmp_path / ".b.lock").write_text("my notes\n")
    before = snapshot(tmp_path)
    for name in (".a.lock", ".b.lock"):
        with pytest.raises(UsageError, match="not a lock file coopsumo made"):
            with _locked(tmp_path / name):
                pass
    assert snapshot(tmp_path) == before
    (tmp_path / ".c.lock").write_text("")  # a stale lock of an earlier version: taken, and removed after
    with _locked(tmp_path / ".c.lock"):
        assert (tmp_path / ".c.lock").read_text().startswith("coopsumo store, pid ")
    assert not (tmp_path / ".c.lock").exists()
