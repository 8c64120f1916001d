"""A pytest plugin (entry point `tessera` in pyproject.toml): a project's own tests say
"this scene still renders the same" in one line,

    def test_cornell_look(tessera_refs):
        tessera_refs.assert_same("tests/refs", "cornell")

against a reference set made with `tessera refs create`. A failing check fails the test
with its verdict and statistics, and leaves the HTML report (reference, new render and
heatmap) under --tessera-report DIR (default: the test's tmp_path).
"""
from __future__ import annotations

from pathlib import Path

import pytest


def pytest_addoption(parser) -> None:
    group = parser.getgroup("tessera", "Tessera reference checks")
    group.addoption("--tessera-report", metavar="DIR", default=None,
                    help="write the HTML report of every tessera_refs check under DIR/TEST_NAME")
    group.addoption("--tessera-strict", action="store_true", default=False,
                    help="fail checks that stay inconclusive at their budget")


class RefsChecker:
    """What the `tessera_refs` fixture gives a test."""

    def __init__(self, report_dir: Path, strict: bool) -> None:
        self.report_dir = report_dir
        self.strict = strict
        self.results = []

    def check(self, folder: str | Path, name: str | None = None, *, scene: str | Path | None = None,
              seed: int | None = None, strict: bool | None = None):
        """Checks reference `name` of the set in `folder` (the only one when None) and writes
        the report; returns the tessera.refcheck.CheckResult without judging it."""
        from tessera import refcheck, refreport, refs

        refset = refs.load(folder)
        if name is None:
            if len(refset.references) != 1:
                raise refs.RefsError(f"{folder} holds {len(refset.references)} references: name one")
            ref = refset.references[0]
        else:
            ref = refset.find(name)
        result = refcheck.check(folder, refset, ref, seed=seed, scene_file=scene,
                                strict=self.strict if strict is None else strict)
        refreport.write_html([result], self.report_dir)
        self.results.append(result)
        return result

    def assert_same(self, folder: str | Path, name: str | None = None, **kwargs):
        """Fails the test unless the scene still renders like its reference."""
        result = self.check(folder, name, **kwargs)
        if not result.passed:
            pytest.fail(f"{result.name}: {result.why}\n{result.comparison.report.summary()}\n"
                        f"report: {self.report_dir / 'index.html'}", pytrace=False)
        return result


@pytest.fixture
def tessera_refs(request, tmp_path) -> RefsChecker:
    base = request.config.getoption("--tessera-report")
    report_dir = Path(base) / request.node.name if base else tmp_path / "tessera-report"
    return RefsChecker(report_dir, request.config.getoption("--tessera-strict"))
