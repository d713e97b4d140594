// The shared pieces of render.hpp (formats, colours, views, layouts) and matrix_picture.
#include "render/render.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <sstream>

#include "common/error.hpp"
#include "distance/analysis.hpp"
#include "render/canvas.hpp"

namespace brenier::render {

using detail::set_colour;
using detail::text;

Format format_of(const std::string& path) {
  std::string ext = path.size() >= 4 ? path.substr(path.size() - 4) : "";
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  if (ext == ".png") return Format::kPng;
  if (ext == ".svg") return Format::kSvg;
  invalid("'" + path + "': a picture is written as .png or .svg");
}

void detail::check_picture_size(int width, int height) {
  if (width < 64 || width > 16384 || height < 64 || height > 16384)
    invalid("picture size " + std::to_string(width) + "x" + std::to_string(height) + " is out of 64..16384 pixels");
}

Rgb checker_colour(bool odd) { return odd ? Rgb{0.16, 0.33, 0.62} : Rgb{0.97, 0.93, 0.80}; }

namespace {
int floor_mod2(double x) { return static_cast<int>(std::floor(x)) & 1; }
// Linear interpolation through evenly spaced colour stops.
Rgb through(const Rgb* stops, int n, double t) {
  t = std::clamp(std::isfinite(t) ? t : 0.5, 0.0, 1.0) * (n - 1);
  const int k = std::min(n - 2, static_cast<int>(t));
  const double a = t - k;
  return {stops[k].r + a * (stops[k + 1].r - stops[k].r), stops[k].g + a * (stops[k + 1].g - stops[k].g),
          stops[k].b + a * (stops[k + 1].b - stops[k].b)};
}
}  // namespace

bool checker_odd_disk(double u, double v) { return ((floor_mod2(8 * u) + floor_mod2(8 * v)) & 1) == 1; }

bool checker_odd_sphere(const Eigen::Vector3d& x) {
  const double step = std::numbers::pi / 12;
  const double lon = std::atan2(x.y(), x.x()), lat = std::asin(std::clamp(x.z() / x.norm(), -1.0, 1.0));
  return ((floor_mod2(lon / step) + floor_mod2(lat / step)) & 1) == 1;
}

Rgb diverging(double t) {
  static const Rgb stops[5] = {{0.02, 0.19, 0.38}, {0.40, 0.66, 0.81}, {0.97, 0.97, 0.97}, {0.84, 0.38, 0.30},
                               {0.40, 0.0, 0.12}};
  return through(stops, 5, t);
}

Rgb sequential(double t) {
  static const Rgb stops[5] = {{0.27, 0.00, 0.33}, {0.23, 0.32, 0.55}, {0.13, 0.57, 0.55}, {0.37, 0.79, 0.38},
                               {0.99, 0.91, 0.14}};
  return through(stops, 5, t);
}

View parse_view(const std::string& s) {
  if (s.empty() || s == "auto") return {};
  std::istringstream in(s);
  View v;
  char comma = 0;
  if (!(in >> v.azimuth_deg >> comma >> v.elevation_deg) || comma != ',' || !in.eof() ||
      !std::isfinite(v.azimuth_deg) || !(std::abs(v.elevation_deg) <= 90))
    invalid("--view '" + s + "': expected auto or AZIMUTH,ELEVATION in degrees (elevation within +-90)");
  v.automatic = false;
  return v;
}

nlohmann::json Layout::json() const {
  auto rect = [](const Rect& r) { return nlohmann::json::array({r.x, r.y, r.w, r.h}); };
  nlohmann::json j{{"width", width}, {"height", height}, {"panels", nlohmann::json::array()},
                   {"bars", nlohmann::json::array()}};
  for (const Panel& p : panels) {
    nlohmann::json q{{"kind", p.kind}, {"title", p.title}, {"row", p.row}, {"rect", rect(p.rect)}};
    if (p.radius > 0) q.update({{"cx", p.cx}, {"cy", p.cy}, {"radius", p.radius}});
    j["panels"].push_back(q);
  }
  for (const ColourBar& b : bars)
    j["bars"].push_back({{"quantity", b.quantity}, {"row", b.row}, {"lo", b.lo}, {"hi", b.hi}, {"rect", rect(b.rect)}});
  return j;
}

// ---- matrices ----------------------------------------------------------------------------

namespace {

void check_matrix(const MatrixFigure& m) {
  const Eigen::Index n = m.d.rows();
  if (n < 1 || m.d.cols() != n)
    invalid("the distance matrix is " + std::to_string(m.d.rows()) + "x" + std::to_string(m.d.cols()) +
            ", not square and non-empty");
  if (m.names.size() != static_cast<size_t>(n))
    invalid(std::to_string(m.names.size()) + " names for a " + std::to_string(n) + "-shape matrix");
  if (!m.labels.empty() && m.labels.size() != static_cast<size_t>(n))
    invalid(std::to_string(m.labels.size()) + " labels for a " + std::to_string(n) + "-shape matrix");
}

// The order of a depth-first walk of the minimum spanning tree (Prim's, O(n^2)) from shape
// 0, children by increasing edge length; unconverged (NaN) pairs count as far.
std::vector<int> tree_order(const Eigen::MatrixXd& d) {
  const int n = static_cast<int>(d.rows());
  auto dist = [&](int i, int j) { return std::isfinite(d(i, j)) ? d(i, j) : std::numeric_limits<double>::max(); };
  std::vector<int> parent(n, -1);
  std::vector<double> best(n, std::numeric_limits<double>::infinity());
  std::vector<bool> in(n, false);
  std::vector<std::vector<std::pair<double, int>>> children(n);
  best[0] = 0;
  for (int step = 0; step < n; ++step) {
    int u = -1;
    for (int i = 0; i < n; ++i)
      if (!in[i] && (u < 0 || best[i] < best[u])) u = i;
    in[u] = true;
    if (parent[u] >= 0) children[parent[u]].push_back({best[u], u});
    for (int i = 0; i < n; ++i)
      if (!in[i] && dist(u, i) < best[i]) best[i] = dist(u, i), parent[i] = u;
  }
  std::vector<int> order, stack{0};
  while (!stack.empty()) {
    const int u = stack.back();
    stack.pop_back();
    order.push_back(u);
    std::sort(children[u].rbegin(), children[u].rend());  // the nearest child popped first
    for (const auto& c : children[u]) stack.push_back(c.second);
  }
  return order;
}

Rgb label_colour(int k) {
  static const Rgb palette[10] = {{0.12, 0.47, 0.71}, {1.0, 0.50, 0.05}, {0.17, 0.63, 0.17}, {0.84, 0.15, 0.16},
                                  {0.58, 0.40, 0.74}, {0.55, 0.34, 0.29}, {0.89, 0.47, 0.76}, {0.5, 0.5, 0.5},
                                  {0.74, 0.74, 0.13}, {0.09, 0.75, 0.81}};
  return palette[k % 10];
}

void heat_map(cairo_t* cr, Format format, const MatrixFigure& m, const std::vector<int>& order, const Rect& r,
              double top, Layout& layout) {
  const int n = static_cast<int>(order.size());
  const double cell = r.w / n;
  detail::raster_layer(cr, format, r, [&](cairo_t* to) {
    cairo_set_antialias(to, CAIRO_ANTIALIAS_NONE);
    for (int a = 0; a < n; ++a)
      for (int b = 0; b < n; ++b) {
        const double v = m.d(order[a], order[b]);
        set_colour(to, std::isfinite(v) ? sequential(top > 0 ? v / top : 0) : Rgb{0.8, 0.8, 0.8});
        cairo_rectangle(to, r.x + b * cell, r.y + a * cell, cell + 0.5, cell + 0.5);
        cairo_fill(to);
      }
  });
  set_colour(cr, {0.1, 0.1, 0.1});
  if (cell >= 6)
    for (int a = 0; a < n; ++a)
      text(cr, m.names[static_cast<size_t>(order[a])], r.x - 4, r.y + (a + 0.5) * cell, std::min(11.0, cell * 0.8), 1,
           0.5);
  // Lines between the label groups.
  cairo_set_line_width(cr, 1);
  for (int a = 1; a < n && !m.labels.empty(); ++a)
    if (m.labels[static_cast<size_t>(order[a])] != m.labels[static_cast<size_t>(order[a - 1])]) {
      cairo_move_to(cr, r.x, r.y + a * cell);
      cairo_line_to(cr, r.x + r.w, r.y + a * cell);
      cairo_move_to(cr, r.x + a * cell, r.y);
      cairo_line_to(cr, r.x + a * cell, r.y + r.h);
    }
  cairo_set_source_rgb(cr, 1, 1, 1);
  cairo_stroke(cr);
  ColourBar bar;
  bar.quantity = "distance";
  bar.lo = 0;
  bar.hi = top;
  bar.rect = {r.x + r.w + 8, r.y, 14, r.h};
  detail::colour_bar(cr, bar, sequential);
  layout.bars.push_back(bar);
  Panel p;
  p.kind = "heatmap";
  p.title = m.labels.empty() ? "distances, tree order" : "distances, by label";
  p.rect = r;
  layout.panels.push_back(p);
}

void mds_plot(cairo_t* cr, const MatrixFigure& m, const Rect& r, Layout& layout) {
  const int n = static_cast<int>(m.d.rows());
  Eigen::MatrixXd d = m.d;
  const double top = d.array().isFinite().select(d.array(), 0).maxCoeff();
  d = d.array().isFinite().select(d.array(), top);  // unconverged pairs as the farthest
  const Eigen::MatrixXd x = distance::classical_mds(d, 2).coordinates;
  const Eigen::Vector2d lo = x.colwise().minCoeff(), hi = x.colwise().maxCoeff();
  const double span = std::max({hi.x() - lo.x(), hi.y() - lo.y(), 1e-300});
  const double s = 0.85 * std::min(r.w, r.h) / span;
  const Eigen::Vector2d mid = (lo + hi) / 2;
  std::map<std::string, int> label_index;
  for (const std::string& l : m.labels) label_index.emplace(l, static_cast<int>(label_index.size()));
  cairo_set_source_rgb(cr, 0.6, 0.6, 0.6);
  cairo_set_line_width(cr, 0.6);
  cairo_rectangle(cr, r.x, r.y, r.w, r.h);
  cairo_stroke(cr);
  for (int i = 0; i < n; ++i) {
    const double px = r.x + r.w / 2 + s * (x(i, 0) - mid.x()), py = r.y + r.h / 2 - s * (x(i, 1) - mid.y());
    set_colour(cr, m.labels.empty() ? label_colour(0) : label_colour(label_index[m.labels[static_cast<size_t>(i)]]));
    cairo_arc(cr, px, py, 4, 0, 2 * std::numbers::pi);
    cairo_fill(cr);
    if (n <= 60) {
      set_colour(cr, {0.2, 0.2, 0.2});
      text(cr, m.names[static_cast<size_t>(i)], px + 6, py, 9, 0, 0.5);
    }
  }
  int k = 0;
  for (const auto& [label, index] : label_index) {
    set_colour(cr, label_colour(index));
    cairo_rectangle(cr, r.x + 8, r.y + 8 + 14 * k, 10, 10);
    cairo_fill(cr);
    set_colour(cr, {0.1, 0.1, 0.1});
    text(cr, label, r.x + 22, r.y + 13 + 14 * k++, 10, 0, 0.5);
  }
  Panel p;
  p.kind = "mds";
  p.title = "classical MDS";
  p.rect = r;
  layout.panels.push_back(p);
}

}  // namespace

std::vector<int> matrix_order(const MatrixFigure& m) {
  check_matrix(m);
  std::vector<int> order = tree_order(m.d);
  if (!m.labels.empty())
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
      return m.labels[static_cast<size_t>(a)] < m.labels[static_cast<size_t>(b)];
    });
  return order;
}

Picture matrix_picture(const MatrixFigure& m, Format format, int width, int height) {
  detail::check_picture_size(width, height);
  const std::vector<int> order = matrix_order(m);
  double top = 0;
  for (double v : m.d.reshaped())
    if (std::isfinite(v)) top = std::max(top, v);
  detail::Canvas canvas(format, width, height);
  cairo_t* cr = canvas.cr();
  Picture p;
  p.layout.width = width;
  p.layout.height = height;
  const double side = std::max(8.0, std::min(height - 60.0, width / 2.0 - 140));
  set_colour(cr, {0.1, 0.1, 0.1});
  text(cr, "distances (" + std::to_string(m.d.rows()) + " shapes)", 8, 6, 14, 0, 0);
  heat_map(cr, format, m, order, {110, 40, side, side}, top, p.layout);
  mds_plot(cr, m, {side + 190, 40, std::max(8.0, width - side - 200), side}, p.layout);
  p.bytes = canvas.finish();
  return p;
}

}  // namespace brenier::render
