"""Independent NumPy/SciPy references of every C++ algorithm. Used by tests and benchmarks only:
they favour clarity over speed and share no code with the core."""
from .coverage import direction_bins, direction_coverage
from .ellipsoid import fit_ellipsoid

__all__ = ["direction_bins", "direction_coverage", "fit_ellipsoid"]
