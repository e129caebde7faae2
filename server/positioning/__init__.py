"""Pure estimation core: numpy/scipy only, no I/O, no settings, no web or storage imports."""
