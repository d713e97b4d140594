// libFuzzer target: arbitrary bytes through one reader, then validation and topology.
// The only acceptable outcome besides success is a brenier::Error of an input kind; any
// crash, sanitizer report, other exception or hang is a bug.
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "common/error.hpp"
#include "mesh/io.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace brenier;
  static const mesh::Format format = *mesh::parse_format(BRENIER_FUZZ_FORMAT);
  // Small limits keep each run fast; the header guards are what is being tested.
  const mesh::ReadLimits limits{.max_bytes = 1 << 20, .max_vertices = 100000, .max_faces = 200000};
  try {
    mesh::PolygonSoup soup =
        mesh::read_soup(std::string_view(reinterpret_cast<const char*>(data), size), format, limits);
    mesh::CleanMesh cm = mesh::clean(soup, {.merge_duplicates = (size & 1) != 0,
                                            .keep_largest_component = (size & 2) != 0,
                                            .fix_orientation = (size & 4) != 0});
    if (cm.mesh.F.rows() > 0 && cm.valid()) (void)mesh::compute_topology(cm.mesh);
  } catch (const Error& e) {
    if (e.code() == ErrorCode::kInternal) std::abort();
  }
  return 0;
}
