"""The one exception every decoder raises for a frame it cannot accept."""


class FrameError(ValueError):
    """A frame that does not fit the expected layout (wrong DLC, unexpected id, corrupted payload).

    The message is the reason, so callers can count the frame and report it as an event instead of crashing.
    """
