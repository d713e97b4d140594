// Pictures of results, drawn with Cairo as PNG or SVG (issue 24): a map as the surface in
// 3-D with the map's checkerboard texture beside its image on the disk or the sphere, the
// distortion colour maps with colour bars and their histograms (the seed's figures of
// sec. 3.3 and 5.3); a distance matrix as a heat map beside its MDS plot (sec. 4.4.2).
// Every picture comes with its layout (panels, colour bars and their ranges) so that the
// callers and the tests can find what was drawn where. No I/O.
#pragma once

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "jobs/jobs.hpp"
#include "mesh/mesh.hpp"

namespace brenier::render {

enum class Format { kPng, kSvg };
/// The format a file name asks for by its extension (.png or .svg, any case); throws
/// Error(kInvalidArgument) naming the file otherwise.
Format format_of(const std::string& path);

struct Rect {
  double x = 0, y = 0, w = 0, h = 0;
};
/// A drawn panel. For the images on the disk or the sphere, (cx, cy) and radius place the
/// unit circle (the disk's boundary, the sphere's outline) in pixels, +v (or the view's up)
/// upwards.
struct Panel {
  std::string kind;  // surface, disk, sphere, area_distortion, angle_distortion, histogram, heatmap, mds
  std::string title;
  int row = 0;  // the map it shows (map_picture's rows)
  Rect rect;
  double cx = 0, cy = 0, radius = 0;
};
/// A vertical colour bar: `lo` at its bottom edge, `hi` at its top edge.
struct ColourBar {
  std::string quantity;  // log_area_ratio, angle_distortion_deg, distance
  int row = 0;
  double lo = 0, hi = 0;
  Rect rect;
};
struct Layout {
  int width = 0, height = 0;
  std::vector<Panel> panels;
  std::vector<ColourBar> bars;
  nlohmann::json json() const;
};
struct Picture {
  std::string bytes;  // the PNG or SVG file
  Layout layout;
};

struct Rgb {
  double r = 0, g = 0, b = 0;
};
/// The checkerboard's two colours.
Rgb checker_colour(bool odd);
/// The texture's square at a point of the disk: squares of side 1/8 in (u, v).
bool checker_odd_disk(double u, double v);
/// On the sphere: cells of 15 degrees of longitude by 15 of latitude.
bool checker_odd_sphere(const Eigen::Vector3d& x);
/// Colour maps on [0, 1]: blue-white-red for signed quantities, dark-to-bright for
/// magnitudes.
Rgb diverging(double t);
Rgb sequential(double t);

/// How the 3-D surface is seen: `automatic` looks along the surface's axis of least spread
/// (a face is seen from the front, a height field from above), with its axis of most spread
/// across the picture; otherwise from azimuth/elevation (degrees) in the mesh's own frame,
/// z up.
struct View {
  bool automatic = true;
  double azimuth_deg = 0, elevation_deg = 0;
};
/// "auto" or "AZ,EL" (degrees); throws Error(kInvalidArgument) for anything else.
View parse_view(const std::string& text);

/// The 3-D panel's direction towards the viewer and its up direction for `view`.
struct SurfaceView {
  Eigen::Vector3d toward, up;
};
SurfaceView surface_view(const mesh::TriMesh& surface, const View& view);

/// One map of a surface: its vertices in 3-D (surface.V may be empty: no 3-D panel) and
/// their images (#V by 3: z = 0 on the disk, or on the unit sphere).
struct MapFigure {
  std::string title;
  mesh::TriMesh surface;
  mesh::Vertices image;
  bool disk = true;
};
/// One row per map: the textured 3-D surface, the image with its mesh lines, the log area
/// ratio and the angle error per face on the image with their colour bars (the log area
/// ratio's runs over +-max |log area ratio|, the angle error's over [0, max], the extremes of
/// quality::measure), and the histograms of both. Throws Error(kInvalidArgument) for sizes
/// out of 64..16384 pixels, no maps, or an image whose rows do not match the surface.
Picture map_picture(const std::vector<MapFigure>& maps, Format format, int width, int height, const View& view = {});

/// The rows of a computed map: the map itself, and for an area-preserving map first the
/// conformal map it started from (titled with `name`, the domain and the method).
std::vector<MapFigure> map_figures(const jobs::MapOutcome& map, const std::string& name);
/// The default sizes: maps 1600 pixels wide and 330 per row, a matrix 1400 x 760.
inline constexpr int kMapPictureWidth = 1600, kMapRowHeight = 330;
inline constexpr int kMatrixPictureWidth = 1400, kMatrixPictureHeight = 760;
/// map_picture of `rows` at the default size and view.
Picture default_map_picture(const std::vector<MapFigure>& rows, Format format);

/// A distance matrix with its shapes' names and, optionally, labels (empty, or one per
/// shape).
struct MatrixFigure {
  Eigen::MatrixXd d;
  std::vector<std::string> names;
  std::vector<std::string> labels;
};
/// The heat map of D (shapes grouped by label, or, without labels, in the order of a walk
/// of the minimum spanning tree, which keeps single-linkage clusters together) with its
/// colour bar over [0, max D], beside the classical-MDS plot coloured by label. Throws
/// Error(kInvalidArgument) for a matrix that is not square, names or labels of the wrong
/// count, or sizes out of range.
Picture matrix_picture(const MatrixFigure& m, Format format, int width, int height);
/// The heat map's order of the shapes (exposed for the tests).
std::vector<int> matrix_order(const MatrixFigure& m);

}  // namespace brenier::render
