"""`--file-progress` (make test): one line per test file as its last test ends, instead of pytest's dots.

pytest's own per-file lines (`tests/test_x.py ....  [ 12%]`) need the default verbosity and one process; with
pytest-xdist (`-n 2`) the dots of both workers share one line and no file is named, and `-v` would print a line
per test (about 1,800). This plugin, registered in the controlling process only (its hooks below, which
tests/conftest.py imports),
counts each file's tests from the collection (the workers' under xdist) and writes, when the last of them ends,

    [ 37%] tests/test_scenario2.py: 42 passed, 1 skipped in 95.2 s

the share of all collected tests finished so far, the file's outcomes and the time its tests took (setup, call
and teardown summed: with `--dist loadfile` one worker runs a file from start to end). The dots are left out
(a failure's traceback and the closing summary are pytest's own); `-o console_output_style=classic` drops
pytest's own percentage, which these lines replace.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Generator, Sequence
from typing import Any

import pytest


def file_of(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def outcome_of(reports: Sequence[pytest.TestReport]) -> str:
    """One test's outcome from its setup, call and teardown reports, in the words of pytest's summary."""
    for report in reports:
        if report.failed:
            return "failed" if report.when == "call" else "error"
    for report in reports:
        if report.skipped:
            return "xfailed" if hasattr(report, "wasxfail") else "skipped"
    if any(hasattr(report, "wasxfail") for report in reports):
        return "xpassed"
    return "passed"


class FileProgress:
    """The plugin: per file, the tests collected, the reports of the tests under way and the outcomes so far."""

    def __init__(self, terminal: Any) -> None:
        self.terminal = terminal
        self.expected: Counter[str] = Counter()
        self.total = 0
        self.finished = 0
        self.reports: dict[str, list[pytest.TestReport]] = defaultdict(list)
        self.outcomes: dict[str, Counter[str]] = defaultdict(Counter)
        self.seconds: Counter[str] = Counter()

    def expect(self, nodeids: Sequence[str]) -> None:
        if not self.total:  # every xdist worker reports the same collection: the first one counts
            self.expected = Counter(file_of(n) for n in nodeids)
            self.total = len(nodeids)

    def pytest_collection_finish(self, session: pytest.Session) -> None:
        self.expect([item.nodeid for item in session.items])  # one process (under xdist the controller has none)

    @pytest.hookimpl(optionalhook=True)
    def pytest_xdist_node_collection_finished(self, node: Any, ids: Sequence[str]) -> None:
        self.expect(ids)

    @pytest.hookimpl(wrapper=True)
    def pytest_report_teststatus(self, report: pytest.TestReport) -> Generator[None, Any, Any]:
        status = yield
        if status and report.when != "collect":  # no dot or letter per test: the file's line says it
            category, _letter, word = status
            return category, "", word
        return status

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        self.reports[report.nodeid].append(report)
        self.seconds[file_of(report.nodeid)] += report.duration

    def pytest_runtest_logfinish(self, nodeid: str) -> None:
        path = file_of(nodeid)
        self.outcomes[path][outcome_of(self.reports.pop(nodeid, []))] += 1
        self.finished += 1
        if sum(self.outcomes[path].values()) == self.expected[path]:
            self.terminal.write_line(self.line(path))

    def line(self, path: str) -> str:
        share = self.finished / self.total if self.total else 1.0
        counts = ", ".join(f"{n} {word}" for word, n in sorted(self.outcomes[path].items(), key=_summary_order))
        return f"[{share:4.0%}] {path}: {counts} in {self.seconds[path]:.1f} s"


def _summary_order(item: tuple[str, int]) -> int:
    order = ("failed", "error", "passed", "skipped", "xfailed", "xpassed")
    return order.index(item[0]) if item[0] in order else len(order)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--file-progress", action="store_true",
                     help="one line per test file as it ends, with the share of tests done (make test)")  # fmt: skip


@pytest.hookimpl(trylast=True)  # after the terminal reporter is made
def pytest_configure(config: pytest.Config) -> None:
    terminal = config.pluginmanager.get_plugin("terminalreporter")
    if config.getoption("file_progress") and terminal is not None and not hasattr(config, "workerinput"):
        config.pluginmanager.register(FileProgress(terminal), "file_progress_lines")
