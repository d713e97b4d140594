"""Python client of the brenier service (conformal maps, area-preserving maps and
Wasserstein shape distances of triangulated surfaces). See clients/python/README.md."""
from .client import BrenierError, Client, DistanceResult, MapResult, NamedMatrix

__all__ = ["Client", "BrenierError", "MapResult", "DistanceResult", "NamedMatrix"]
__version__ = "0.24.0"
