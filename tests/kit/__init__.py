"""The tests' kit: everything the tiers share, so that no test module imports another
(tests/unit/test_kit_rules.py holds that rule). Fixtures that several modules use live in
a conftest.py (tests/, or the tier's), built from the kit.

Monitor documents and runs
- documents: Monitor documents from Python values (as dicts, YAML text, loaded, compiled),
  and a file of them in a test's directory
- speed_run: the speed-limit run of ``edgerv check``'s tests (documents, events, types)
- odom_run: the odometry run the live handler's tests replay, and random traces of it
- checks: events from rows, a check over them, its verdicts; a formula's truth per step
- randomruns: random assertions, events and runs of the side-by-side tests
- sidebyside: what those compare (a runtime's state, a check's outcome, two engines)
- traces: the JSON Lines, MCAP and rosbag2 sqlite3 writers, with the ROS definitions
- ros_numpy: each ROS primitive type's NumPy dtype
- dense, reference: the oracles (dense-time semantics, a reference monitor)
- counts: how many seeds or examples a random test runs (``make fuzz``: more)

Running edgerv and its parts
- cli: ``edgerv`` in this process or as a process of its own
- engines: an engine's manual clock and the robot's feed from a thread
- handoff_pair: two engines behind real HTTP APIs and a TCP gate (fixture ``pair``)
- sockets: a client sending a byte at a time
- bounded: a call that may hang fails instead
- pki: the CA, server and client certificates of the TLS tests

Processes, images, clusters
- ros: the ROS process harness (a handler process, publishers, replay, migrate, a node of
  the test's own) and ``ros_env``, the one environment builder of ROS 2 processes (the
  benches' bench/ros_env.py too)
- robotrun: a robot's run for the handler as installed (docker run, systemd)
- own_types: a robot's own interface packages, monitors on them, their publisher and bag
- dockerimage: the handler's image, built once
- kube, chart: kubectl on the e2e cluster, the chart installed, Monitor resources
"""
