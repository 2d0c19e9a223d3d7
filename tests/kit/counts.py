"""How much a random test runs: its seeds (:func:`scaled`) or Hypothesis examples
(:func:`props`), the unit tier's count, or ``$EDGERV_PROPERTY_EXAMPLES`` under ``make
fuzz`` (which runs every test module that calls either)."""

from __future__ import annotations

import os
from typing import Any

PROPERTY_EXAMPLES = int(os.environ.get("EDGERV_PROPERTY_EXAMPLES", "0"))


def scaled(count: int) -> int:
    """A random test's count of seeds or runs: ``count`` in the unit tier (derandomized),
    ``$EDGERV_PROPERTY_EXAMPLES`` under ``make fuzz``."""
    return PROPERTY_EXAMPLES or count


def props(examples: int) -> Any:
    """Hypothesis settings of the property tests: ``examples`` derandomized examples (CI),
    or ``$EDGERV_PROPERTY_EXAMPLES`` random ones (``make fuzz``)."""
    from hypothesis import HealthCheck, settings

    return settings(
        max_examples=PROPERTY_EXAMPLES or examples,
        deadline=None,
        derandomize=not PROPERTY_EXAMPLES,
        database=None,
        print_blob=True,
        suppress_health_check=[
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
            HealthCheck.filter_too_much,
        ],
    )
