"""Reading and writing: LAS/LAZ and COPC files, CRS and units, ASPRS classes, the in-memory Cloud."""
from gfjax.io.atomic import atomic_output, check_output
from gfjax.io.cloud import Cloud
from gfjax.io.las import expand_inputs, read, read_header, write
from gfjax.io.units import Units

__all__ = ["Cloud", "Units", "atomic_output", "check_output", "expand_inputs", "read", "read_header", "write"]
