"""Reading and writing LAS/LAZ, units, ASPRS classes, tiles."""
from gfjax.io.cloud import Cloud

__all__ = ["Cloud"]
