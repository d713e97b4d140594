"""Python client of the brenier service (conformal maps, area-preserving maps,
Wasserstein shape distances and registration of triangulated surfaces). See clients/python/README.md."""
from .client import BrenierError, Client, DistanceResult, MapResult, NamedMatrix, RegisterResult

__all__ = ["Client", "BrenierError", "MapResult", "DistanceResult", "NamedMatrix", "RegisterResult"]
__version__ = "0.25.0"
