"""fluxcal — calibration and error compensation of magnetic-field and current sensors.

    import fluxcal
    cal = fluxcal.fit_ellipsoid(readings)          # readings: N×3, or a fluxcal.io.Recording
    fields = cal.apply(readings)                   # h = A (m − b)
    cal.save("cal.json"); fluxcal.Calibration.load("cal.json")
"""
try:
    from . import _core
except ImportError as err:  # Python's own words for a missing module here blame "a circular import"
    from pathlib import Path as _Path
    _here = _Path(__file__).parent
    _missing = not any(_here.glob("_core*.so")) and "_core" in str(err)
    _why = (f"there is no _core*.so in {_here} (a source tree whose C++ core is not built or not copied here)"
            if _missing else f"{err}")
    raise ImportError(f"fluxcal's compiled core cannot be loaded: {_why}. Install the package (pip install ., or "
                      "make install), or copy the built module beside this file (cp build/dev/python/_core*.so "
                      "python/fluxcal/)") from (None if _missing else err)
from .alignment import Alignment, align_to_gravity
from .calibration import Calibration
from .coverage import direction_coverage
from .diagnose import detection_limits, diagnose, diagnose_cable
from .bounds import crlb
from .ellipsoid import EllipsoidMoments, fit_ellipsoid
from .io import Recording, read_csv, read_recording, write_csv, write_recording
from .pipeline import calibrate
from .planar import calibrate_planar  # yaw-only / biaxial: the two axes of the turning plane
from .refine import fit_vector, refine
from .twostep import TwoStep2D, twostep, twostep_2d
from . import positions  # noqa: E402  (fluxcal.positions: multi-position calibration, seed 002)
from . import cable
from . import drift, kalman, timeseries  # seed 001: drift compensation, AR Kalman filters, time-series tests

__version__ = _core.__version__

__all__ = ["Alignment", "Calibration", "EllipsoidMoments", "Recording", "TwoStep2D", "align_to_gravity", "calibrate", "calibrate_planar", "crlb", "detection_limits", "diagnose", "diagnose_cable", "direction_coverage",
           "fit_ellipsoid", "fit_vector", "read_csv", "read_recording", "refine", "twostep", "twostep_2d", "write_csv", "write_recording",
           "__version__", "cmake_dir"]


def cmake_dir() -> str:
    """Folder holding fluxcalConfig.cmake of the C++ library inside this installed package:
    `cmake -DCMAKE_PREFIX_PATH=$(python -m fluxcal --cmake-dir)` lets C++ code find_package(fluxcal)."""
    from importlib.resources import files
    from pathlib import Path

    here = Path(str(files("fluxcal")))
    found = sorted(here.glob("lib*/**/fluxcalConfig.cmake"))
    if not found:
        raise FileNotFoundError(f"the fluxcal at {here} carries no C++ library: a source checkout on PYTHONPATH, or "
                                "a build without install rules? The installed wheel carries it (pip install ., make "
                                "install); `make cpp` builds the C++ library alone")
    return str(found[0].parent)
