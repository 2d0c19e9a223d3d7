import sys
from pathlib import Path
from typing import Any

# tests/helpers.py and tests/reference.py are imported by name from every tier
sys.path.insert(0, str(Path(__file__).parent))


TIERS = ("unit", "integration", "e2e")


def pytest_collection_modifyitems(items: list[Any]) -> None:
    """Run the tiers in order, fast to slow: unit, integration, e2e. The e2e tier brings a
    cluster up for the rest of the session (its fixture is session-wide); its control plane,
    kubelets and pods must not share the CPUs with the integration tier's timing-sensitive
    runs (the case study pins a real-time loop to one CPU)."""

    def tier(item: Any) -> int:
        parts = Path(str(item.fspath)).parts
        return next((i for i, t in enumerate(TIERS) if t in parts), len(TIERS))

    items.sort(key=tier)  # stable: the order within a tier is kept
