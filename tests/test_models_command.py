"""`coopsumo models` on a store that is not there yet (a fresh clone): "no models yet" and where they would go,
exit code 0; a --store named by hand that does not exist, or a file, is still one line and exit code 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from coopsumo.studies.engine import model_store


def test_a_missing_default_store_has_no_models_yet(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(model_store.STORE_ENV, raising=False)
    assert model_store.main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("no models yet") and "results/models" in out
    assert not (tmp_path / "results").exists()  # listing makes nothing


def test_a_missing_store_from_the_environment_or_an_empty_one_has_no_models_yet(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.setenv(model_store.STORE_ENV, str(tmp_path / "store"))
    assert model_store.main([]) == 0
    assert capsys.readouterr().out.startswith(f"no models yet in {tmp_path / 'store'}")
    (tmp_path / "store").mkdir()
    assert model_store.main(["--store", str(tmp_path / "store")]) == 0
    assert capsys.readouterr().out.startswith("no models yet")


@pytest.mark.parametrize("kind", ["missing", "file"])
def test_a_named_store_that_is_no_folder_is_one_line_and_exit_2(
        kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    store = tmp_path / "store"
    if kind == "file":
        store.write_text("x")
    assert model_store.main(["--store", str(store)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--store" in err[0] and str(store) in err[0]
