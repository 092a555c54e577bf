"""The committed protocol studies a profile pairs with (Profile.paired_with), checked before any cell runs: a folder
under results/ (or results/history/), never out of it, whose study.json and runs.csv hold inside the schemas the
protocol writes its own by (record_schemas.PROTOCOL_STUDY, study_tables.PROTOCOL_RUNS: each cell's row once). A bad
record is refused in one line naming the file, the row and the column, exit 2, before anything is written (issue 82,
probe 7, I7: a 999 m/s speed printed a -976.50 difference, a duplicate row was used; I11: a study.json that is not
JSON was a traceback after every cell had run). A folder without both files is not refused: the report says it is
not paired (report.committed_runs), as beside an installed wheel."""

from __future__ import annotations

from typing import Any

from coopsumo.errors import UsageError
from coopsumo.files import read_json
from coopsumo.record_schemas import PROTOCOL_STUDY, RecordError
from coopsumo.studies.protocol.plan import folder_problem


def check_paired(profile: Any, results: Any = None) -> None:
    """UsageError in one line when a study the profile pairs with (Profile.paired_with, under `results`: the
    repository's committed results/ by default, report.COMMITTED) is named out of results/ or holds a record that
    breaks its schema (module docstring); nothing when it has none or lacks study.json or runs.csv."""
    from coopsumo.studies.protocol import report
    from coopsumo.study_tables import PROTOCOL_RUNS

    results = report.COMMITTED if results is None else results
    for _, folder, _ in profile.paired_with:
        if problem := folder_problem(folder):
            raise UsageError(f"profile {profile.name}: {problem}")
        where = report.committed_folder(results, folder)
        study, runs = where / "study.json", where / "runs.csv"
        if not study.is_file() or not runs.is_file():
            continue
        try:
            PROTOCOL_STUDY.check(read_json(study), study)
        except OSError as err:
            raise UsageError(f"profile {profile.name} pairs with {study}, which cannot be read "
                             f"({err.strerror or type(err).__name__})") from None  # fmt: skip
        except RecordError as err:
            raise UsageError(f"profile {profile.name} pairs with {err}") from None
        except ValueError:
            raise UsageError(f"profile {profile.name} pairs with {study}, which is not JSON (damaged, cut short or "
                             "edited)") from None  # fmt: skip
        try:
            PROTOCOL_RUNS.read(runs)
        except RecordError as err:
            raise UsageError(f"profile {profile.name} pairs with {err}") from None
