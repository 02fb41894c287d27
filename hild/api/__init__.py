"""The Zenoh room: the daemon's Zenoh face in the client domain, and the Python client library.

eclipse-zenoh is imported here and nowhere else (docs/architecture.md, "Rules"). One module, one job.

Shared by server and client:

- ``keys``          the key layout ``hild/<robot>/…``
- ``codec``         strict JSON in (size guard, no NaN, decoding caps), always-valid JSON out
- ``session``       Zenoh configs: the daemon's (loopback, no scouting by default) and the clients'

The server side, run by the client domain (``hild.daemon``), which reaches the cycle through a ``CycleLink``:

- ``server``        ``ApiServer``: declares everything, publishes status, events and outputs, answers services
- ``ports``         controller inputs (subscribers), outputs (publishers of sample rings) and goal endpoints
- ``goals``         ``GoalEndpoint``: a controller's goals, client half (accept, cancel, results, feedback)
- ``services``      the control-plane services, independent of Zenoh (bytes in, reply dict out)
- ``fields``        what every service request is checked against: its fields' validators, its size
- ``lifecycle``     load, configure, unload, reload controllers while the robot runs (services)
- ``parameters``    controllers' and the daemon's own parameters while the robot runs, and the tuned config (services)
- ``queries``       admitting and answering queries: size and in-flight caps, the large-payload worker
- ``unique``        one robot name, one daemon: refuse to start beside another, report one that appears
- ``goal_senders``  goal senders' liveliness tokens: a sender that goes away is told to its controllers
- ``ros2/``         the ROS 2 face: rmw_zenoh's keys, CDR, type hashes (docs/ros2.md)

The client library:

- ``client``        ``HildClient``: the Python client (``from hild.client import HildClient``)
- ``aio``           its asyncio face
- ``ctl``           ``hild ctl``, with ``render`` for its text output
- ``pub``           ``hild ctl pub``: streams values to a controller input on an absolute schedule
- ``stream_inputs`` which input of a controller ``pub`` streams to, and how many values it takes
- ``expressions``   ``pub``'s values: numbers and expressions of ``t``, evaluated by simpleeval (no ``eval``)

The wire format is documented in docs/protocol.md.
"""
