"""The operator's names are written once (edgerv_operator/constants.py) and the YAML that
cannot import them says the same: the Monitor CRD, the chart's RBAC rules on Monitors, its
tier label, and the settings the chart hands the operator, each one a variable it reads."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from edgerv.core.documents import API_VERSION
from edgerv_operator.config import VARIABLES, OperatorConfig
from edgerv_operator.constants import (
    FINALIZER,
    GROUP,
    HANDLER_PORT,
    KIND,
    MONITORS,
    PLACEMENT_SECONDS,
    PLURAL,
    TIER_LABEL,
    TIERS,
    VERSION,
)

ROOT = Path(__file__).parents[2]
CHART = ROOT / "helm" / "edgerv"


def test_the_crd_names_the_resource_the_operator_watches() -> None:
    crd = yaml.safe_load((ROOT / "crds" / f"{PLURAL}.{GROUP}.yaml").read_text())
    spec = crd["spec"]
    assert crd["metadata"]["name"] == f"{PLURAL}.{GROUP}"
    assert (spec["group"], spec["names"]["plural"], spec["names"]["kind"]) == (GROUP, PLURAL, KIND)
    assert [v["name"] for v in spec["versions"]] == [VERSION]
    assert MONITORS == (GROUP, VERSION, PLURAL)
    assert f"{GROUP}/{VERSION}" == API_VERSION  # the handlers' Monitor document's
    assert FINALIZER == "edgerv.io/monitor"  # on Monitors in clusters: a rename strands them


def test_the_charts_rules_on_monitors_name_their_group() -> None:
    """Every RBAC rule of the chart on Monitors names the CRD's group, and no rule names
    another group for them."""
    rules = 0
    for template in (CHART / "templates").glob("*.yaml"):
        text = template.read_text()
        for groups, resources in re.findall(
            r"apiGroups: \[([^\]]*)\]\s*\n\s*resources: \[([^\]]*)\]", text
        ):
            if PLURAL in {r.strip().split("/")[0] for r in resources.split(",")}:
                assert [g.strip() for g in groups.split(",")] == [GROUP], (template, groups)
                rules += 1
    assert rules >= 4  # the operator's two, the view and edit roles, the uninstall hook's


def test_the_chart_sets_only_variables_the_operator_reads_and_its_defaults() -> None:
    values = yaml.safe_load((CHART / "values.yaml").read_text())
    assert values["handler"]["tierLabel"] == TIER_LABEL
    assert values["handler"]["port"] == HANDLER_PORT
    assert tuple(values["operator"]["tiers"]) == TIERS
    assert values["operator"]["placementSeconds"] == PLACEMENT_SECONDS
    for name in ("operator-deployment.yaml", "uninstall-hook.yaml", "tests/handlers-answer.yaml"):
        given = set(re.findall(r"- name: (EDGERV_\w+)", (CHART / "templates" / name).read_text()))
        assert given and given <= set(VARIABLES), (name, given - set(VARIABLES))
    assert (
        OperatorConfig.from_env(
            {"EDGERV_TOKEN": "t", "EDGERV_NAMESPACE": "n", "EDGERV_PLAIN_HTTP": "true"}
        ).tiers
        == TIERS
    )
