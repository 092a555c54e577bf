"""Issue 82, probe 13: a flag's number is read as it is written. F15: int() and float() took '٣', '１００' and '1_0'
(3, 100, 10), which every record refuses; F16: a value over its limit by less than a float's precision was rounded
onto the limit and taken, and `--gamma 0.99999999999999999999` was refused as "got 1.0"."""

from __future__ import annotations

from pathlib import Path

import pytest

from coopsumo.cli import main as cli_main


def main(argv: list[str]) -> int:
    try:
        return cli_main(argv)
    except SystemExit as stop:  # argparse's error, in this process
        return int(stop.code or 0)

CASES = [
    # F15: non-ASCII digits, underscores
    ("simulate", "--lanes", "٣"), ("simulate", "--seed", "٣"), ("simulate", "--steps", "１００"),
    ("simulate", "--t-up", "１.５"), ("simulate", "--seed", "1_0"), ("train", "--alpha", "２"),
    ("scenario2", "--alphas", "٠,٢"), ("scenario2", "--workers", "١"), ("train", "--replay-size", "٣"),
    ("train", "--lr", "1_0e-3"), ("scenario1", "--mobil-p", "0,1_0"), ("scenario1", "--train-seeds", "1_0"),
    ("scenario1", "--train-seeds", "١٠١"),
    # F16: over the limit by less than a float's precision
    ("simulate", "--t-up", "3600.00000000000001"), ("train", "--epsilon-start", "1.00000000000000001"),
    ("train", "--alpha", "1000.00000000000001"), ("train", "--lr", "1.00000000000000001"),
    ("simulate", "--speed-limit", "70.000000000000001"), ("train", "--gamma", "0.99999999999999999999"),
    ("scenario2", "--alphas", "0,1000.00000000000000001"),
]  # fmt: skip


@pytest.mark.parametrize(("command", "flag", "value"), CASES)
def test_a_flag_takes_ascii_digits_and_its_limits_as_written(command: str, flag: str, value: str, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    extra = ["--profile", "tiny"] if command == "scenario2" else ["--quick"] if command == "scenario1" else []
    code = main([command, *extra, flag, value, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "error" in err[0], err
    assert flag in err[0] and value in err[0], err[0]  # the value as given, never rounded
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("policy", ["mobil:p=٠", "mobil:p=10.0000000000000000001", "mobil:p=1_0"])
def test_a_policy_strings_number_is_read_as_written(policy: str, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["simulate", "--policy", policy, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "p must be a finite number >= 0 and <= 10" in err[0], err


def test_the_limits_themselves_are_taken() -> None:
    """A value at its limit, written any way, is inside it (the limits are read as their shortest decimals)."""
    from coopsumo.field_rules import decimal_outside, number

    assert number(0.1, 3600.0)("0.1") == 0.1 and number(0.1, 3600.0)("3600.000") == 3600.0
    assert not decimal_outside("0.1", 0.1, None) and decimal_outside("0.0999999999999999999999", 0.1, None)
    assert decimal_outside("1", 0.0, 1.0, high_open=True) and not decimal_outside("0.999", 0.0, 1.0, high_open=True)
