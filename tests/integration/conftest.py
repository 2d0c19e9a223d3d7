import zlib

import pytest


@pytest.fixture
def domain(request: pytest.FixtureRequest) -> int:
    """A ROS domain of the test's own (0..101 are valid for Fast DDS on one host)."""
    return 20 + zlib.crc32(request.node.name.encode()) % 80
