#include <fluxcal/twostep.hpp>
