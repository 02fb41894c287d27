"""hild: a hardware-in-the-loop bridge daemon for robot arms."""
