"""Built-in controllers (found through the hild.controllers entry-point group)."""
