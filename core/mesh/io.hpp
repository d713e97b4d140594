// Mesh files: OBJ, OFF, PLY (ascii and binary), STL (ascii and binary) read through
// OpenMesh's readers into a PolygonSoup, FreeSurfer binary triangle surfaces (lh.pial, ...)
// with a reader of ours; OBJ (with per-vertex vt), PLY, OFF and FreeSurfer written by us.
//
// Every reader is safe on untrusted bytes: counts declared in a header are checked against
// the number of bytes present before anything is allocated from them, and every failure is
// a brenier::Error(kInvalidArgument) whose message names the format and the problem.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "mesh/mesh.hpp"

namespace brenier::mesh {

enum class Format { kObj, kOff, kPly, kStl, kFreeSurfer };

const char* format_name(Format f);
/// "obj", "off", "ply", "stl", "freesurfer" (also "fs"); case-insensitive; nullopt otherwise.
std::optional<Format> parse_format(std::string_view name);
/// Format of a file from its first bytes (FreeSurfer magic 0xFFFFFE), then its extension,
/// then a look at its first bytes ("OFF", "ply", "solid", "v "). Throws kInvalidArgument
/// naming the file when nothing fits.
Format detect_format(std::string_view path, std::string_view head);

struct ReadLimits {
  int64_t max_bytes = int64_t{4} << 30;  // 4 GiB
  int64_t max_vertices = 50'000'000;
  int64_t max_faces = 100'000'000;
};

/// Parses a whole file's bytes. Throws Error(kInvalidArgument) for corrupt or truncated
/// data, Error(kResourceExhausted) for data over the limits.
PolygonSoup read_soup(std::string_view bytes, Format format, const ReadLimits& limits = {});

/// Reads a file (format detected when not given). Throws kNotFound when it cannot be
/// opened, and as read_soup otherwise.
PolygonSoup read_soup_file(const std::string& path, std::optional<Format> format = std::nullopt,
                           const ReadLimits& limits = {});

/// Whole file into memory, with the size checked against limits.max_bytes.
std::string read_file_bytes(const std::string& path, const ReadLimits& limits = {});

/// The per-vertex texture coordinates of an OBJ file's text (`vt u v` lines, as write_mesh_string
/// writes them): nullopt when it has none. Throws Error(kInvalidArgument) when they are not
/// one per vertex (another count than `vertices`, or a face corner `a/b` with b != a).
std::optional<UV> read_obj_uv(std::string_view text, int64_t vertices);

/// Serializes a triangle mesh. `uv` (#V by 2), when given, is written as `vt u v` per vertex
/// for OBJ (faces as `f a/a b/b c/c`) and as u, v vertex properties for PLY; OFF and
/// FreeSurfer ignore it. Coordinates are written with 17 significant digits, so an ascii
/// round trip is exact; PLY is binary little-endian doubles. FreeSurfer stores float32.
std::string write_mesh_string(const TriMesh& mesh, Format format, const UV* uv = nullptr);
/// The same into a file (format from the extension unless given). Throws kInvalidArgument
/// when the file cannot be written.
void write_mesh_file(const std::string& path, const TriMesh& mesh, const UV* uv = nullptr,
                     std::optional<Format> format = std::nullopt);

}  // namespace brenier::mesh
