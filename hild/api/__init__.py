"""The Zenoh room: server, message schemas, Python client."""
