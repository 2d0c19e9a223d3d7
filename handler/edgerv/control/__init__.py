"""The control plane: the handlers' control API as its callers and its server share it
(the wire types, TLS, the token), the client, the handoff driven from outside
(``migrate``), the placement policy and the orchestrator that applies it, and the
commands ``edgerv migrate`` and ``edgerv orchestrate``. The operator uses it; it never
imports the handler (``edgerv.handler``), nor rclpy nor kopf."""
