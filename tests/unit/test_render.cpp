// Pictures (core/render): properties of what was drawn, read back from the PNG's pixels,
// never golden bytes.
#include <cairo.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>

#include "expect_error.hpp"
#include "mesh/shapes.hpp"
#include "quality/quality.hpp"
#include "render/render.hpp"

namespace brenier::render {
namespace {

// The PNG's pixels, read back with Cairo.
class Pixels {
 public:
  explicit Pixels(const std::string& png) : data_(png) {
    surface_ = cairo_image_surface_create_from_png_stream(read, this);
    EXPECT_EQ(cairo_surface_status(surface_), CAIRO_STATUS_SUCCESS);
    cairo_surface_flush(surface_);
  }
  ~Pixels() { cairo_surface_destroy(surface_); }
  int width() const { return cairo_image_surface_get_width(surface_); }
  int height() const { return cairo_image_surface_get_height(surface_); }
  Rgb at(int x, int y) const {
    const unsigned char* row = cairo_image_surface_get_data(surface_) + y * cairo_image_surface_get_stride(surface_);
    uint32_t p;
    std::memcpy(&p, row + 4 * x, 4);
    return {((p >> 16) & 255) / 255.0, ((p >> 8) & 255) / 255.0, (p & 255) / 255.0};
  }
  bool white(int x, int y) const {
    const Rgb c = at(x, y);
    return c.r == 1 && c.g == 1 && c.b == 1;
  }

 private:
  static cairo_status_t read(void* closure, unsigned char* out, unsigned int length) {
    auto* self = static_cast<Pixels*>(closure);
    if (self->at_ + length > self->data_.size()) return CAIRO_STATUS_READ_ERROR;
    std::memcpy(out, self->data_.data() + self->at_, length);
    self->at_ += length;
    return CAIRO_STATUS_SUCCESS;
  }
  std::string data_;
  size_t at_ = 0;
  cairo_surface_t* surface_ = nullptr;
};

double colour_gap(const Rgb& a, const Rgb& b) {
  return std::max({std::abs(a.r - b.r), std::abs(a.g - b.g), std::abs(a.b - b.b)});
}

// The hemisphere and its stereographic projection onto the unit disk (a conformal map with a
// known image, sec. 2.6): z -> (x, y) / (1 + z).
MapFigure hemisphere_map(int rings) {
  MapFigure m;
  m.title = "hemisphere";
  m.surface = mesh::make_hemisphere(rings);
  m.image.resize(m.surface.V.rows(), 3);
  for (Eigen::Index i = 0; i < m.surface.V.rows(); ++i) {
    const Eigen::Vector3d p = m.surface.V.row(i);
    m.image.row(i) << p.x() / (1 + p.z()), p.y() / (1 + p.z()), 0;
  }
  return m;
}

const Panel& panel(const Layout& l, const std::string& kind) {
  for (const Panel& p : l.panels)
    if (p.kind == kind) return p;
  throw std::runtime_error("no panel " + kind);
}

TEST(Render, TheDiskImageCoversTheUnitDisksPixelsAndNothingOutside) {
  const Picture p = map_picture({hemisphere_map(24)}, Format::kPng, 1180, 300);
  const Pixels px(p.bytes);
  ASSERT_EQ(px.width(), 1180);
  ASSERT_EQ(px.height(), 300);
  const Panel& d = panel(p.layout, "disk");
  ASSERT_GT(d.radius, 50);
  int inside = 0, outside = 0;
  for (int y = static_cast<int>(d.rect.y); y < static_cast<int>(d.rect.y + d.rect.h); ++y)
    for (int x = static_cast<int>(d.rect.x); x < static_cast<int>(d.rect.x + d.rect.w); ++x) {
      const double r = std::hypot(x + 0.5 - d.cx, y + 0.5 - d.cy);
      if (r < d.radius - 1) {
        ++inside;
        EXPECT_FALSE(px.white(x, y)) << "pixel " << x << "," << y << " inside the disk is not drawn";
      } else if (r > d.radius + 1.5) {
        ++outside;
        EXPECT_TRUE(px.white(x, y)) << "pixel " << x << "," << y << " outside the disk is drawn";
      }
    }
  EXPECT_GT(inside, 3 * d.radius * d.radius);
  EXPECT_GT(outside, 0);
}

TEST(Render, AKnownFaceIsDrawnInItsCheckerColour) {
  const MapFigure m = hemisphere_map(6);
  const Picture p = map_picture({m}, Format::kPng, 1180, 300);
  const Pixels px(p.bytes);
  const Panel& d = panel(p.layout, "disk");
  int checked = 0;
  for (int f = 0; f < m.surface.num_faces(); ++f) {
    // The face's incentre in the picture, if it is at least 3 pixels from the face's sides and
    // from the checker squares' sides.
    Eigen::Vector2d c[3];
    for (int k = 0; k < 3; ++k) {
      const auto q = m.image.row(m.surface.F(f, k));
      c[k] = {d.cx + d.radius * q.x(), d.cy - d.radius * q.y()};
    }
    const double a = (c[1] - c[2]).norm(), b = (c[2] - c[0]).norm(), e = (c[0] - c[1]).norm();
    const Eigen::Vector2d in = (a * c[0] + b * c[1] + e * c[2]) / (a + b + e);
    const double s = (a + b + e) / 2, inradius = std::sqrt((s - a) * (s - b) * (s - e) / s);
    const double u = (in.x() - d.cx) / d.radius, v = (d.cy - in.y()) / d.radius;
    auto from_side = [&](double t) { return std::abs(t * 8 - std::round(t * 8)) / 8 * d.radius; };
    if (inradius < 4 || from_side(u) < 3 || from_side(v) < 3) continue;
    const Rgb got = px.at(static_cast<int>(in.x()), static_cast<int>(in.y()));
    EXPECT_LT(colour_gap(got, checker_colour(checker_odd_disk(u, v))), 2.5 / 255) << "face " << f;
    ++checked;
  }
  EXPECT_GT(checked, 10);
}

TEST(Render, TheColourBarsEndsAreTheQualityExtremes) {
  const MapFigure m = hemisphere_map(10);
  const quality::MapQuality q = quality::measure(m.surface, m.image, quality::Target::kPlane);
  const Picture p = map_picture({m}, Format::kPng, 1180, 300);
  const Pixels px(p.bytes);
  ASSERT_EQ(p.layout.bars.size(), 2u);
  const ColourBar& area = p.layout.bars[0];
  const ColourBar& angle = p.layout.bars[1];
  EXPECT_EQ(area.quantity, "log_area_ratio");
  EXPECT_DOUBLE_EQ(area.hi, q.area_distortion_log_abs.max);
  EXPECT_DOUBLE_EQ(area.lo, -q.area_distortion_log_abs.max);
  EXPECT_EQ(angle.quantity, "angle_distortion_deg");
  EXPECT_DOUBLE_EQ(angle.lo, 0);
  EXPECT_DOUBLE_EQ(angle.hi, q.angle_distortion_deg.max);
  EXPECT_GT(angle.hi, 0);
  struct Case {
    const ColourBar* bar;
    Rgb (*map)(double);
  };
  for (const Case& k : {Case{&area, diverging}, Case{&angle, sequential}}) {
    const Rect& r = k.bar->rect;
    const int x = static_cast<int>(r.x + r.w / 2);
    EXPECT_LT(colour_gap(px.at(x, static_cast<int>(r.y + 2)), k.map(1)), 0.06) << k.bar->quantity << " top";
    EXPECT_LT(colour_gap(px.at(x, static_cast<int>(r.y + r.h - 2)), k.map(0)), 0.06) << k.bar->quantity << " bottom";
  }
}

TEST(Render, TheSphereImageFillsItsOutlineAndTwoMapsMakeTwoRows) {
  MapFigure s;
  s.title = "sphere";
  s.surface = mesh::make_icosphere(3);
  s.image = s.surface.V;
  s.disk = false;
  const Picture p = map_picture({s, hemisphere_map(8)}, Format::kPng, 1180, 600);
  const Pixels px(p.bytes);
  EXPECT_EQ(px.height(), 600);
  const Panel& d = panel(p.layout, "sphere");
  EXPECT_EQ(d.row, 0);
  for (int y = static_cast<int>(d.rect.y); y < static_cast<int>(d.rect.y + d.rect.h); ++y)
    for (int x = static_cast<int>(d.rect.x); x < static_cast<int>(d.rect.x + d.rect.w); ++x) {
      const double r = std::hypot(x + 0.5 - d.cx, y + 0.5 - d.cy);
      if (r < 0.97 * d.radius) {
        EXPECT_FALSE(px.white(x, y)) << x << "," << y;
      } else if (r > d.radius + 1.5) {
        EXPECT_TRUE(px.white(x, y)) << x << "," << y;
      }
    }
  EXPECT_EQ(panel(p.layout, "disk").row, 1);
  EXPECT_EQ(p.layout.bars.size(), 4u);
}

TEST(Render, SvgHasTheRequestedSize) {
  const Picture p = map_picture({hemisphere_map(4)}, Format::kSvg, 900, 240);
  ASSERT_EQ(p.bytes.rfind("<?xml", 0), 0u);
  EXPECT_NE(p.bytes.find("width=\"900px\""), std::string::npos);
  EXPECT_NE(p.bytes.find("height=\"240px\""), std::string::npos);
  EXPECT_NE(p.bytes.find("</svg>"), std::string::npos);
}

TEST(Render, TheHeatMapGroupsLabelsAndColoursItsDiagonalAsZero) {
  // Two clusters on a line: a at 0, 0.1, 0.2; b at 5, 5.1, 5.2, interleaved in the input.
  const double x[6] = {0, 5, 0.1, 5.1, 0.2, 5.2};
  MatrixFigure m;
  m.d.resize(6, 6);
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) m.d(i, j) = std::abs(x[i] - x[j]);
  m.names = {"a0", "b0", "a1", "b1", "a2", "b2"};
  const std::vector<int> tree = matrix_order(m);
  // Without labels, the tree walk keeps each cluster together.
  for (int k = 0; k < 6; ++k) EXPECT_EQ(x[tree[k]] < 1, (k < 3) == (x[tree[0]] < 1)) << k;
  m.labels = {"b", "a", "b", "a", "b", "a"};
  const std::vector<int> order = matrix_order(m);
  for (int k = 0; k < 3; ++k) EXPECT_EQ(m.labels[order[k]], "a");
  const Picture p = matrix_picture(m, Format::kPng, 900, 420);
  const Pixels px(p.bytes);
  EXPECT_EQ(px.width(), 900);
  ASSERT_EQ(p.layout.bars.size(), 1u);
  EXPECT_DOUBLE_EQ(p.layout.bars[0].lo, 0);
  EXPECT_DOUBLE_EQ(p.layout.bars[0].hi, 5.2);
  const Panel& h = panel(p.layout, "heatmap");
  const double cell = h.rect.w / 6;
  for (int k = 0; k < 6; ++k) {
    const int cx = static_cast<int>(h.rect.x + (k + 0.5) * cell), cy = static_cast<int>(h.rect.y + (k + 0.5) * cell);
    EXPECT_LT(colour_gap(px.at(cx, cy), sequential(0)), 1.5 / 255);
  }
  EXPECT_NO_THROW(panel(p.layout, "mds"));
}

TEST(Render, BadRequestsAreRefusedByName) {
  const MapFigure m = hemisphere_map(3);
  EXPECT_ERROR(map_picture({m}, Format::kPng, 10, 300), ErrorCode::kInvalidArgument, "out of 64..16384");
  MapFigure wrong = m;
  wrong.image.conservativeResize(3, 3);
  EXPECT_ERROR(map_picture({wrong}, Format::kPng, 600, 300), ErrorCode::kInvalidArgument, "image points");
  EXPECT_ERROR(map_picture({}, Format::kPng, 600, 300), ErrorCode::kInvalidArgument, "no map");
  EXPECT_ERROR(format_of("figure.jpg"), ErrorCode::kInvalidArgument, ".png or .svg");
  EXPECT_EQ(format_of("A.SVG"), Format::kSvg);
  EXPECT_ERROR(parse_view("30;20"), ErrorCode::kInvalidArgument, "AZIMUTH,ELEVATION");
  EXPECT_FALSE(parse_view("30,20").automatic);
  MatrixFigure bad;
  bad.d = Eigen::MatrixXd::Zero(2, 3);
  bad.names = {"a", "b"};
  EXPECT_ERROR(matrix_picture(bad, Format::kPng, 600, 300), ErrorCode::kInvalidArgument, "not square");
}

}  // namespace
}  // namespace brenier::render
