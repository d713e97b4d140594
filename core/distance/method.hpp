// The two shape distances (sec. 4.4): the exact Wasserstein distance between the surfaces'
// conformal densities (Alg. 5) and the OMT-map distance of Def. 2.24 as a linear embedding.
// A header of its own so that the requests (core/jobs/requests.hpp) and the front ends that
// only parse them need none of the numerics.
#pragma once

#include <optional>
#include <string>
#include <string_view>

namespace brenier::distance {

enum class Method { kWasserstein, kOmtLinear };
const char* method_name(Method m);
/// "wasserstein" or "omt-linear"; nullopt otherwise.
std::optional<Method> find_method(std::string_view name);
/// The same, throwing Error(kInvalidArgument) naming the choices.
Method parse_method(const std::string& name);

}  // namespace brenier::distance
