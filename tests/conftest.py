import sys
from pathlib import Path
from typing import Any

import pytest

# the kit (tests/kit: kit.documents, kit.ros, ...) is imported by name from every tier
sys.path.insert(0, str(Path(__file__).parent))


TIERS = ("unit", "integration", "e2e")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--tiers",
        default=None,
        help="the test tiers to run, comma-separated: unit, integration, e2e, or all "
        "(default: the unit tier, and the tier of any path named inside tests/integration "
        "or tests/e2e; `make test` runs all)",
    )


def _tier(path: Path) -> int:
    parts = path.parts
    return next((i for i, t in enumerate(TIERS) if t in parts), len(TIERS))


def _wanted(config: pytest.Config) -> set[str]:
    """The tiers this run asked for: --tiers, else the unit tier and those of the paths
    named inside a tier's directory (`pytest tests/integration/test_migrate.py` runs it)."""
    given = config.getoption("tiers")
    if given:
        names = {t.strip() for t in given.split(",") if t.strip()}
        unknown = names - {*TIERS, "all"}
        if unknown:
            raise pytest.UsageError(
                f"--tiers: unknown tier {', '.join(sorted(unknown))} "
                f"(the tiers: {', '.join(TIERS)}, or all)"
            )
        return set(TIERS) if "all" in names else names
    wanted = {"unit"}
    for arg in config.args:
        index = _tier(Path(arg.split("::", 1)[0]).resolve())
        if index < len(TIERS):
            wanted.add(TIERS[index])
    return wanted


def pytest_collection_modifyitems(config: pytest.Config, items: list[Any]) -> None:
    """Run the tiers asked for (a plain `pytest` runs the fast unit tier only), in order,
    fast to slow: unit, integration, e2e. The e2e tier brings a cluster up for the rest of
    the session (its fixture is session-wide); its control plane, kubelets and pods must
    not share the CPUs with the integration tier's timing-sensitive runs (the case study
    pins a real-time loop to one CPU)."""
    wanted = _wanted(config)
    keep, skipped = [], []
    for item in items:
        index = _tier(Path(str(item.fspath)))
        (keep if index == len(TIERS) or TIERS[index] in wanted else skipped).append(item)
    if skipped:
        config.hook.pytest_deselected(items=skipped)
        names = {TIERS[_tier(Path(str(i.fspath)))] for i in skipped}
        tiers = [t for t in TIERS if t in names]
        config._edgerv_skipped_tiers = tiers  # type: ignore[attr-defined]
    keep.sort(key=lambda item: _tier(Path(str(item.fspath))))  # stable within a tier
    items[:] = keep


def pytest_report_header(config: pytest.Config) -> str:
    return f"edgerv tiers: {', '.join(t for t in TIERS if t in _wanted(config))}"


def pytest_terminal_summary(terminalreporter: Any, config: pytest.Config) -> None:
    tiers = getattr(config, "_edgerv_skipped_tiers", None)
    if tiers:
        terminalreporter.write_line(
            f"edgerv: the {' and '.join(tiers)} tier(s) were not run: pass --tiers all "
            "(make test does) or name their directory"
        )
