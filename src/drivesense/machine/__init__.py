"""Physics of the machine: drives, friction and the cutting process (no I/O)."""

__all__ = []
