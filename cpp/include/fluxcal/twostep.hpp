// fluxcal/twostep.hpp — TWOSTEP calibration (placeholder: being written).
#pragma once

#include "fluxcal/types.hpp"

namespace fluxcal {}  // namespace fluxcal
