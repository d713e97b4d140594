// The parameter domains a surface is mapped onto: the unit disk (topological disks) and the
// unit sphere (closed genus-0 surfaces). A header without the mesh types, so that the job
// requests (core/jobs/requests.hpp) and the thin client that parses them need none.
#pragma once

#include <optional>
#include <string_view>

namespace brenier::mesh {

enum class Domain { kDisk, kSphere };
const char* domain_name(Domain d);  // "disk", "sphere"
std::optional<Domain> find_domain(std::string_view name);

}  // namespace brenier::mesh
