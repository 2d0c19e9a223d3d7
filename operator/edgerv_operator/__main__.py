"""``edgerv-operator``: run the operator (``kopf run`` on its handlers).

It watches the namespaces of ``EDGERV_WATCH_NAMESPACES`` (comma-separated), or all.
"""

from __future__ import annotations

import os

from kopf.cli import main as kopf_cli


def main() -> None:
    namespaces = [n.strip() for n in os.environ.get("EDGERV_WATCH_NAMESPACES", "").split(",")]
    scope = [a for n in namespaces if n for a in ("--namespace", n)] or ["--all-namespaces"]
    kopf_cli(
        args=["run", "--standalone", *scope, "-m", "edgerv_operator.handlers"],
        prog_name="edgerv-operator",
    )


if __name__ == "__main__":
    main()
