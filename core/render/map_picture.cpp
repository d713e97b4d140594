// map_picture: one row per map (render.hpp). The 3-D view is orthographic with faces drawn
// back to front (painter's order), each textured by the affine map from its image triangle
// to the screen, then shaded by a headlight; the sphere's images are seen from one side.
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <numeric>

#include "common/error.hpp"
#include "quality/quality.hpp"
#include "render/canvas.hpp"
#include "render/render.hpp"

namespace brenier::render {
namespace {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;
using detail::set_colour;
using detail::text;

constexpr double kChecks = 8;  // checker squares per unit of (u, v): side 1/8

// An orthographic camera: `toward` points from the scene to the viewer, (right, up, toward)
// right-handed; a point p lands at o + scale (p - centre).(right, -up) in pixels.
struct Camera {
  Vec3 centre = Vec3::Zero(), right = Vec3::UnitX(), up = Vec3::UnitY(), toward = Vec3::UnitZ();
  double scale = 1;
  Vec2 o = Vec2::Zero();
  Vec2 px(const Vec3& p) const {
    const Vec3 q = p - centre;
    return {o.x() + scale * q.dot(right), o.y() - scale * q.dot(up)};
  }
  double depth(const Vec3& p) const { return (p - centre).dot(toward); }
};

Camera oriented(const Vec3& toward, const Vec3& up_hint) {
  Camera c;
  c.toward = toward.normalized();
  Vec3 right = up_hint.cross(c.toward);
  if (right.norm() < 1e-9) right = Vec3::UnitY().cross(c.toward);
  c.right = right.normalized();
  c.up = c.toward.cross(c.right);
  return c;
}

Vec3 face_normal(const mesh::Vertices& V, const mesh::Faces& F, int f) {
  return (V.row(F(f, 1)) - V.row(F(f, 0))).cross(V.row(F(f, 2)) - V.row(F(f, 0))).transpose();
}

// View::automatic: facing the surface's mean normal where it has one (an open surface such
// as a face or a height field: at least a fifth of its area faces one way), otherwise along
// its axis of least spread from the side most of its area faces; the axis of most spread
// across the picture.
Camera surface_orientation(const mesh::TriMesh& s, const View& view) {
  const Vec3 centre = s.V.colwise().mean().transpose();
  Camera c;
  if (view.automatic) {
    const auto X = s.V.rowwise() - centre.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(X.transpose() * X);
    Vec3 mean_normal = Vec3::Zero();
    double area = 0;
    for (int f = 0; f < s.num_faces(); ++f) {
      mean_normal += face_normal(s.V, s.F, f);
      area += face_normal(s.V, s.F, f).norm();
    }
    Vec3 toward = eig.eigenvectors().col(0);
    if (mean_normal.norm() > 0.2 * area)
      toward = mean_normal.normalized();
    else if (mean_normal.dot(toward) < 0)
      toward = -toward;
    Vec3 across = eig.eigenvectors().col(2) - eig.eigenvectors().col(2).dot(toward) * toward;
    if (across.norm() < 1e-6) across = eig.eigenvectors().col(1);
    c = oriented(toward, toward.cross(across.normalized()));
  } else {
    const double az = view.azimuth_deg * std::numbers::pi / 180, el = view.elevation_deg * std::numbers::pi / 180;
    c = oriented(Vec3(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el)), Vec3::UnitZ());
  }
  return c;
}

Camera surface_camera(const mesh::TriMesh& s, const View& view, const Rect& r) {
  const Vec3 centre = s.V.colwise().mean().transpose();
  Camera c = surface_orientation(s, view);
  c.centre = centre;
  double ex = 1e-12, ey = 1e-12;
  for (Eigen::Index i = 0; i < s.V.rows(); ++i) {
    const Vec3 q = s.V.row(i).transpose() - centre;
    ex = std::max(ex, std::abs(q.dot(c.right)));
    ey = std::max(ey, std::abs(q.dot(c.up)));
  }
  c.scale = 0.46 * std::min(r.w / ex, r.h / ey);
  c.o = {r.x + r.w / 2, r.y + r.h / 2};
  return c;
}

// The camera of an image panel: the unit disk seen from +z, or the unit sphere from a fixed
// side (30 degrees above its equator), filling the panel's square.
Camera domain_camera(bool disk, const Rect& r) {
  const double a = -60 * std::numbers::pi / 180, e = 30 * std::numbers::pi / 180;
  Camera c = disk ? oriented(Vec3::UnitZ(), Vec3::UnitY())
                  : oriented(Vec3(std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e)), Vec3::UnitZ());
  c.scale = 0.46 * std::min(r.w, r.h);
  c.o = {r.x + r.w / 2, r.y + r.h / 2};
  return c;
}

// The faces to draw, back to front; `front_only` drops those facing away (the far side of
// the sphere).
std::vector<int> painter_order(const mesh::Vertices& X, const mesh::Faces& F, const Camera& c, bool front_only) {
  std::vector<int> order;
  std::vector<double> depth(static_cast<size_t>(F.rows()));
  for (int f = 0; f < F.rows(); ++f) {
    const Vec3 g = (X.row(F(f, 0)) + X.row(F(f, 1)) + X.row(F(f, 2))).transpose() / 3;
    depth[static_cast<size_t>(f)] = c.depth(g);
    if (!front_only || face_normal(X, F, f).dot(c.toward) > 0) order.push_back(f);
  }
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return depth[a] < depth[b]; });
  return order;
}

void triangle_path(cairo_t* cr, const Vec2 (&p)[3]) {
  cairo_move_to(cr, p[0].x(), p[0].y());
  cairo_line_to(cr, p[1].x(), p[1].y());
  cairo_line_to(cr, p[2].x(), p[2].y());
  cairo_close_path(cr);
}

// The checker pattern placed so that screen point p of the triangle shows the texture at
// its (u, v): the affine map screen -> pattern (kChecks (u, v)) through the three corners.
bool place_texture(cairo_pattern_t* pattern, const Vec2 (&s)[3], const Vec2 (&uv)[3]) {
  Eigen::Matrix2d S, T;
  S << s[1] - s[0], s[2] - s[0];
  T << kChecks * (uv[1] - uv[0]), kChecks * (uv[2] - uv[0]);
  if (std::abs(S.determinant()) < 1e-9) return false;
  const Eigen::Matrix2d A = T * S.inverse();
  const Vec2 b = kChecks * uv[0] - A * s[0];
  // Flat instead where a check would be under a pixel across (the texture would alias) or
  // the placement is near singular: Cairo leaves its context in error (out of memory) for
  // the extreme placements of an area-preserving map's slivers (mannequin-devil).
  const double det = std::abs(A.determinant());
  if (!A.allFinite() || !b.allFinite() || A.norm() > 1 || !(det > 1e-10)) return false;
  cairo_matrix_t m;
  cairo_matrix_init(&m, A(0, 0), A(1, 0), A(0, 1), A(1, 1), b.x(), b.y());
  cairo_pattern_set_matrix(pattern, &m);
  return true;
}

Vec3 centroid(const mesh::Vertices& X, const mesh::Faces& F, int f) {
  return (X.row(F(f, 0)) + X.row(F(f, 1)) + X.row(F(f, 2))).transpose() / 3;
}

void surface_panel(cairo_t* cr, const MapFigure& m, const Rect& r, const View& view) {
  const Camera c = surface_camera(m.surface, view, r);
  const Vec3 light = (c.toward + 0.35 * c.up + 0.25 * c.right).normalized();
  cairo_pattern_t* pattern = detail::checker_pattern();
  cairo_set_antialias(cr, CAIRO_ANTIALIAS_NONE);  // no seams between neighbouring faces
  for (int f : painter_order(m.surface.V, m.surface.F, c, false)) {
    Vec2 s[3], uv[3];
    for (int k = 0; k < 3; ++k) {
      s[k] = c.px(m.surface.V.row(m.surface.F(f, k)).transpose());
      uv[k] = m.image.row(m.surface.F(f, k)).head<2>().transpose();
    }
    triangle_path(cr, s);
    if (m.disk && place_texture(pattern, s, uv))
      cairo_set_source(cr, pattern);
    else
      set_colour(cr, checker_colour(m.disk ? checker_odd_disk(uv[0].x(), uv[0].y())
                                           : checker_odd_sphere(centroid(m.image, m.surface.F, f).normalized())));
    cairo_fill_preserve(cr);
    const double lit = 0.3 + 0.7 * std::abs(face_normal(m.surface.V, m.surface.F, f).normalized().dot(light));
    cairo_set_source_rgba(cr, 0, 0, 0, 1 - lit);
    cairo_fill(cr);
  }
  cairo_set_antialias(cr, CAIRO_ANTIALIAS_DEFAULT);
  cairo_pattern_destroy(pattern);
}

// The image's faces (on the disk, or the sphere's near side) filled by `fill(f)`, which sets
// the source; then the mesh lines where the faces are wide enough to show them, and the
// unit circle.
template <class Fill>
void image_faces(cairo_t* cr, const MapFigure& m, const Camera& c, Fill fill) {
  const std::vector<int> order = painter_order(m.image, m.surface.F, c, !m.disk);
  cairo_set_antialias(cr, CAIRO_ANTIALIAS_NONE);
  double edge_px = 0;
  for (int f : order) {
    Vec2 s[3];
    for (int k = 0; k < 3; ++k) s[k] = c.px(m.image.row(m.surface.F(f, k)).transpose());
    edge_px += (s[1] - s[0]).norm();
    triangle_path(cr, s);
    fill(f, s);
    cairo_fill(cr);
  }
  cairo_set_antialias(cr, CAIRO_ANTIALIAS_DEFAULT);
  if (!order.empty() && edge_px / static_cast<double>(order.size()) >= 5) {
    cairo_set_source_rgba(cr, 0.15, 0.15, 0.15, 0.55);
    cairo_set_line_width(cr, 0.5);
    for (int f : order) {
      Vec2 s[3];
      for (int k = 0; k < 3; ++k) s[k] = c.px(m.image.row(m.surface.F(f, k)).transpose());
      triangle_path(cr, s);
    }
    cairo_stroke(cr);
  }
  cairo_set_source_rgb(cr, 0.2, 0.2, 0.2);
  cairo_set_line_width(cr, 0.8);
  cairo_arc(cr, c.o.x(), c.o.y(), c.scale, 0, 2 * std::numbers::pi);
  cairo_stroke(cr);
}

Panel image_panel(const char* kind, const std::string& title, int row, const Rect& r, const Camera& c) {
  Panel p;
  p.kind = kind;
  p.title = title;
  p.row = row;
  p.rect = r;
  p.cx = c.o.x();
  p.cy = c.o.y();
  p.radius = c.scale;
  return p;
}

void checker_image(cairo_t* cr, const MapFigure& m, const Camera& c) {
  cairo_pattern_t* pattern = detail::checker_pattern();
  // Disk: one placement for every face, (u, v) -> pixel being the camera's.
  cairo_matrix_t mat;
  cairo_matrix_init(&mat, kChecks / c.scale, 0, 0, -kChecks / c.scale, -kChecks * c.o.x() / c.scale,
                    kChecks * c.o.y() / c.scale);
  cairo_pattern_set_matrix(pattern, &mat);
  image_faces(cr, m, c, [&](int f, const Vec2(&)[3]) {
    if (m.disk)
      cairo_set_source(cr, pattern);
    else
      set_colour(cr, checker_colour(checker_odd_sphere(centroid(m.image, m.surface.F, f).normalized())));
  });
  cairo_pattern_destroy(pattern);
}

struct Distortion {
  Eigen::VectorXd log_area, angle;  // per face
  double max_log = 0, max_angle = 0;
};

Distortion distortion(const MapFigure& m) {
  const quality::MapQuality q =
      quality::measure(m.surface, m.image, m.disk ? quality::Target::kPlane : quality::Target::kSphere);
  Distortion d;
  d.log_area = q.area_distortion_log;
  d.angle = q.angle_distortion;
  d.max_log = q.area_distortion_log_abs.max;
  d.max_angle = q.angle_distortion_deg.max;
  return d;
}

double unit(double v, double lo, double hi) { return hi > lo ? std::clamp((v - lo) / (hi - lo), 0.0, 1.0) : 0.5; }

void histogram(cairo_t* cr, const Eigen::VectorXd& v, double lo, double hi, Rgb (*map)(double), const Rect& r,
               const std::string& title) {
  constexpr int kBins = 40;
  std::vector<int> count(kBins, 0);
  for (double x : v)
    if (std::isfinite(x)) ++count[static_cast<size_t>(std::min(kBins - 1.0, std::floor(unit(x, lo, hi) * kBins)))];
  const int top = std::max(1, *std::max_element(count.begin(), count.end()));
  const Rect plot{r.x + 4, r.y + 18, r.w - 8, r.h - 34};
  const double bw = plot.w / kBins;
  for (int b = 0; b < kBins; ++b) {
    const double h = plot.h * count[static_cast<size_t>(b)] / top;
    set_colour(cr, map((b + 0.5) / kBins));
    cairo_rectangle(cr, plot.x + b * bw, plot.y + plot.h - h, bw, h);
    cairo_fill(cr);
  }
  cairo_set_source_rgb(cr, 0.2, 0.2, 0.2);
  cairo_set_line_width(cr, 0.8);
  cairo_move_to(cr, plot.x, plot.y + plot.h);
  cairo_line_to(cr, plot.x + plot.w, plot.y + plot.h);
  cairo_stroke(cr);
  text(cr, title + " (faces, max bin " + std::to_string(top) + ")", r.x + 4, r.y + 2, 10, 0, 0);
  text(cr, detail::number(lo), plot.x, plot.y + plot.h + 3, 10, 0, 0);
  text(cr, detail::number(hi), plot.x + plot.w, plot.y + plot.h + 3, 10, 1, 0);
}

// The distortion panels and histograms of one row, starting at x with squares of side `side`.
void distortion_panels(cairo_t* cr, Format format, const MapFigure& m, int row, double x, double y, double side,
                       Layout& layout) {
  const Distortion d = distortion(m);
  struct Quantity {
    const char *kind, *quantity, *title;
    const Eigen::VectorXd* v;
    double lo, hi;
    Rgb (*map)(double);
  };
  const Quantity qs[2] = {
      {"area_distortion", "log_area_ratio", "log area ratio", &d.log_area, -d.max_log, d.max_log, diverging},
      {"angle_distortion", "angle_distortion_deg", "angle error (deg)", &d.angle, 0, d.max_angle, sequential}};
  for (const Quantity& q : qs) {
    const Rect r{x, y, side, side};
    const Camera c = domain_camera(m.disk, r);
    detail::raster_layer(cr, format, r, [&](cairo_t* to) {
      image_faces(to, m, c, [&](int f, const Vec2(&)[3]) { set_colour(to, q.map(unit((*q.v)[f], q.lo, q.hi))); });
    });
    set_colour(cr, {0.1, 0.1, 0.1});
    text(cr, q.title, r.x + r.w / 2, r.y - 4, 12, 0.5, 1);
    layout.panels.push_back(image_panel(q.kind, q.title, row, r, c));
    ColourBar bar;
    bar.quantity = q.quantity;
    bar.row = row;
    bar.lo = q.lo;
    bar.hi = q.hi;
    bar.rect = {x + side + 6, y + 0.1 * side, 12, 0.8 * side};
    detail::colour_bar(cr, bar, q.map);
    layout.bars.push_back(bar);
    x += side * 1.3;
  }
  const Rect top{x, y, side, side / 2}, bottom{x, y + side / 2, side, side / 2};
  histogram(cr, d.log_area, -d.max_log, d.max_log, diverging, top, "log area ratio");
  histogram(cr, d.angle, 0, d.max_angle, sequential, bottom, "angle error (deg)");
  Panel h;
  h.kind = "histogram";
  h.title = "histograms";
  h.row = row;
  h.rect = {x, y, side, side};
  layout.panels.push_back(h);
}

void check_map(const MapFigure& m, size_t k) {
  const std::string which = "map " + std::to_string(k + 1);
  if (m.surface.num_faces() == 0) invalid(which + " has no faces");
  if (m.image.rows() != m.surface.V.rows())
    invalid(which + ": " + std::to_string(m.image.rows()) + " image points for " +
            std::to_string(m.surface.V.rows()) + " vertices");
  if (!m.image.allFinite() || !m.surface.V.allFinite()) invalid(which + " has non-finite coordinates");
  if (m.surface.F.minCoeff() < 0 || m.surface.F.maxCoeff() >= m.surface.V.rows())
    invalid(which + " has a face index out of range");
}

}  // namespace

SurfaceView surface_view(const mesh::TriMesh& surface, const View& view) {
  const Camera c = surface_orientation(surface, view);
  return {c.toward, c.up};
}

std::vector<MapFigure> map_figures(const jobs::MapOutcome& map, const std::string& name) {
  const std::string domain = map.disk ? "disk" : "sphere";
  std::vector<MapFigure> out;
  auto add = [&](const mesh::Vertices& image, const std::string& method) {
    MapFigure f;
    f.title = name + " on the " + domain + ", " + method;
    f.surface = map.surface;
    f.image = image;
    f.disk = map.disk;
    out.push_back(std::move(f));
  };
  if (map.conformal.rows() > 0) add(map.conformal, "conformal");
  add(map.positions, map.conformal.rows() > 0 ? "area-preserving" : "conformal");
  return out;
}

Picture default_map_picture(const std::vector<MapFigure>& rows, Format format) {
  return map_picture(rows, format, kMapPictureWidth, kMapRowHeight * static_cast<int>(rows.size()));
}

Picture map_picture(const std::vector<MapFigure>& maps, Format format, int width, int height, const View& view) {
  detail::check_picture_size(width, height);
  if (maps.empty()) invalid("no map to draw");
  for (size_t k = 0; k < maps.size(); ++k) check_map(maps[k], k);
  detail::Canvas canvas(format, width, height);
  cairo_t* cr = canvas.cr();
  Picture p;
  p.layout.width = width;
  p.layout.height = height;
  const int rows = static_cast<int>(maps.size());
  const double row_h = static_cast<double>(height) / rows;
  // Five squares and two colour bars' room per row: 3-D, image, two distortion maps, histograms.
  const double side = std::max(16.0, std::min(width / 5.9, row_h - 44));
  for (int k = 0; k < rows; ++k) {
    const MapFigure& m = maps[static_cast<size_t>(k)];
    const double y = k * row_h + 36;
    set_colour(cr, {0.1, 0.1, 0.1});
    text(cr, m.title, 8, k * row_h + 4, 14, 0, 0);
    const Rect s{side * 0.05, y, side, side};
    Panel surface;
    surface.kind = "surface";
    surface.title = "surface";
    surface.row = k;
    surface.rect = s;
    detail::raster_layer(cr, format, s, [&](cairo_t* to) { surface_panel(to, m, s, view); });
    p.layout.panels.push_back(surface);
    const Rect r{side * 1.15, y, side, side};
    const Camera c = domain_camera(m.disk, r);
    detail::raster_layer(cr, format, r, [&](cairo_t* to) { checker_image(to, m, c); });
    set_colour(cr, {0.1, 0.1, 0.1});
    text(cr, m.disk ? "on the disk" : "on the sphere", r.x + r.w / 2, r.y - 4, 12, 0.5, 1);
    p.layout.panels.push_back(image_panel(m.disk ? "disk" : "sphere", "image", k, r, c));
    distortion_panels(cr, format, m, k, side * 2.3, y, side, p.layout);
  }
  p.bytes = canvas.finish();
  return p;
}

}  // namespace brenier::render
