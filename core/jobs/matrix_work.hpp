// A matrix job's work written down as a file, so that processes other than brenierd (Slurm
// array tasks, Kubernetes pods) compute any of its tiles exactly as brenierd's own pool would
// (sec. 4.4: each shape prepared once into the shared cache, then tiles of pairs, merged
// byte-identical whatever ran them). The file names every option that changes a value, the
// shapes in matrix order with their final (unique) names, the mesh files and their formats.
#pragma once

#include <string>
#include <vector>

#include "distance/matrix.hpp"
#include "jobs/requests.hpp"

namespace brenier::jobs {

struct MatrixWork {
  struct Shape {
    std::string name;    // unique within the matrix
    std::string path;    // the mesh file (absolute, on the volume every node mounts)
    std::string format;  // obj, off, ply, stl, freesurfer (mesh::parse_format)
  };
  MatrixRequest request;     // markers: one per shape or none
  std::vector<Shape> shapes;
  std::string cache;         // the shape cache shared by every task
  int tiles = 1;             // the matrix's split: tile I of `tiles`
};

/// Writes it as JSON (a temporary file then a rename: whole or absent). Doubles are written
/// so that they read back to the same bits.
void write_matrix_work(const MatrixWork& work, const std::string& path);
/// Reads and checks it; Error(kInvalidArgument) naming the file and the field otherwise.
MatrixWork read_matrix_work(const std::string& path);

/// The shapes of the work read from their files, cleaned and made ready (shape_input), on
/// `threads` threads. Error(kInvalidArgument) naming the file when one is gone or invalid.
std::vector<distance::ShapeInput> matrix_inputs(const MatrixWork& work, int threads);

/// Names made unique the way brenierd does it: a name given to several meshes gets "#" and
/// the first 12 characters of its id appended.
void unique_names(std::vector<std::string>& names, const std::vector<std::string>& ids);

}  // namespace brenier::jobs
