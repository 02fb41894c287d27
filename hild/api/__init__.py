"""The Zenoh room: server, message schemas, Python client.

eclipse-zenoh is imported here and nowhere else. One module, one job:

- ``keys``     the key layout ``hild/<robot>/…`` shared by server and client
- ``codec``    strict JSON in (size guard, no NaN), always-valid JSON out
- ``session``  Zenoh configs: the daemon's (loopback, no scouting by default) and the clients'
- ``services`` the control-plane services, independent of Zenoh (bytes in, reply dict out)
- ``ports``    controller inputs (subscribers) and outputs (publishers of sample rings)
- ``server``   ``ApiServer``: the daemon's Zenoh face, on the asyncio side
- ``client``   ``HildClient``: the Python client
- ``ctl``      ``hild ctl``, with ``render`` for its text output

The wire format is documented in docs/protocol.md.
"""
