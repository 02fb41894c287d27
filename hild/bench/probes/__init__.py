"""Floor probes: each library hild's cycle leans on, timed alone with no hild code in the path.

``zenoh_loopback`` (Zenoh between two processes, and the decoy daemon of the interference windows),
``can_virtual`` (python-can's virtual bus), ``mj_step`` (MuJoCo's step). The measuring room may import these
libraries directly, like the tests (docs/architecture.md, "Rooms").
"""
