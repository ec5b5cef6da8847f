// Bindings of twostep.hpp.
#include "bindings.hpp"

#include <fluxcal/twostep.hpp>

namespace fluxcal_py {

void bind_twostep(py::module_&) {}

}  // namespace fluxcal_py
