"""Independent NumPy/SciPy references of every C++ algorithm. Used by tests and benchmarks only:
they favour clarity over speed and share no code with the core."""
from .alignment import align_to_gravity
from .coverage import direction_bins, direction_coverage
from .ellipsoid import fit_ellipsoid, fit_ellipsoid_als
from .refine import refine
from .vector import crlb_vector, fit_vector
from . import planar, serial, twostep

__all__ = ["align_to_gravity", "crlb_vector", "direction_bins", "direction_coverage", "fit_ellipsoid", "fit_ellipsoid_als",
           "fit_vector", "planar", "refine", "serial", "twostep"]
