#include "fluxcal/twostep.hpp"
