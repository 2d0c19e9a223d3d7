"""The operator's names, each written once: the Monitor resource (its API group, version,
plural and kind), the finalizer the operator puts on Monitors, the label keys it reads,
and its settings' defaults (:mod:`edgerv_operator.config` reads the settings).

The Monitor resource is the handlers' Monitor document as a Kubernetes resource: its
apiVersion and kind are the document's (:data:`edgerv.core.documents.API_VERSION`). The
CRD (crds/monitors.edgerv.io.yaml) and the chart (helm/edgerv) spell the same names in
YAML; tests/unit/test_operator_constants.py holds them to these.
"""

from __future__ import annotations

from edgerv.core.documents import API_VERSION
from edgerv.core.documents import KIND as KIND  # "Monitor"
from edgerv.core.robots import ROBOT_LABEL as ROBOT_LABEL  # the nodes' label naming their robot

GROUP, _, VERSION = API_VERSION.partition("/")  # edgerv.io, v1alpha1
PLURAL = "monitors"
MONITORS = (GROUP, VERSION, PLURAL)  # the resource, as Kopf's decorators and the API name it

FINALIZER = f"{GROUP}/monitor"  # on every Monitor the operator places, until it removed it
TIER_LABEL = f"{GROUP}/tier"  # the node label whose value is the node's tier (the default)
HANDLER_SELECTOR = "app.kubernetes.io/name=edgerv,app.kubernetes.io/component=handler"
HANDLER_PORT = 8470  # the handlers' control API port (host networking: each node's address)
TIERS = ("edge", "cloud")  # lowest first
PLACEMENT_SECONDS = 5.0  # between two rounds of the placement policy
LIVENESS = "http://0.0.0.0:8080/healthz"  # where Kopf answers the liveness probe
HANDLER_CONTAINER = "handler"  # the handler pods' container: its CPU limit is the budget
# The budget of the handlers of one tier (EDGERV_BUDGET_TIER; none by default), in cores:
# the least and the most the planner sets, the share of a budget a change must pass,
# and the seconds a changed budget stays (edgerv.core.planner.BudgetConfig)
BUDGET_FLOOR, BUDGET_CEILING, BUDGET_HYSTERESIS, BUDGET_WAIT = 0.1, 1.0, 0.1, 2.0

# in a pod: its service account's token (the operator, the self-test and the uninstall
# hook then log in with it, else with $KUBECONFIG)
SERVICE_ACCOUNT_TOKEN = "/var/run/secrets/kubernetes.io/serviceaccount/token"
