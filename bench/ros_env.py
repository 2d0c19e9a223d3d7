"""The environment of a bench's ROS 2 processes: a domain of the bench's own, discovery on
this host only (nothing leaves the machine), unbuffered output, the handlers' API token."""

from __future__ import annotations

import os


def ros_env(domain: str) -> dict[str, str]:
    return dict(
        os.environ,
        ROS_DOMAIN_ID=domain,
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        PYTHONUNBUFFERED="1",
        EDGERV_TOKEN="bench",
    )
