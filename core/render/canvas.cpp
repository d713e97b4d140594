#include "render/canvas.hpp"

#include <cairo-svg.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "common/error.hpp"

namespace brenier::render::detail {
namespace {

cairo_status_t append(void* closure, const unsigned char* data, unsigned int length) {
  static_cast<std::string*>(closure)->append(reinterpret_cast<const char*>(data), length);
  return CAIRO_STATUS_SUCCESS;
}

void check(cairo_status_t s, const char* what) {
  if (s != CAIRO_STATUS_SUCCESS) fail(ErrorCode::kInternal, std::string(what) + ": " + cairo_status_to_string(s));
}

}  // namespace

Canvas::Canvas(Format format, int width, int height) : format_(format) {
  surface_ = format == Format::kPng ? cairo_image_surface_create(CAIRO_FORMAT_RGB24, width, height)
                                    : cairo_svg_surface_create_for_stream(append, &svg_, width, height);
  check(cairo_surface_status(surface_), "cannot create the picture");
  // Pixels, as the PNG (Cairo's default unit, points, shows it a third larger in browsers).
  if (format == Format::kSvg) cairo_svg_surface_set_document_unit(surface_, CAIRO_SVG_UNIT_PX);
  cr_ = cairo_create(surface_);
  check(cairo_status(cr_), "cannot draw the picture");
  cairo_set_source_rgb(cr_, 1, 1, 1);
  cairo_paint(cr_);
}

Canvas::~Canvas() {
  if (cr_) cairo_destroy(cr_);
  if (surface_) cairo_surface_destroy(surface_);
}

std::string Canvas::finish() {
  check(cairo_status(cr_), "drawing the picture failed");
  cairo_destroy(cr_);
  cr_ = nullptr;
  std::string out;
  if (format_ == Format::kPng) {
    cairo_surface_flush(surface_);
    check(cairo_surface_write_to_png_stream(surface_, append, &out), "cannot encode the PNG");
  } else {
    cairo_surface_finish(surface_);  // flushes the SVG into svg_
    check(cairo_surface_status(surface_), "cannot write the SVG");
    out = std::move(svg_);
  }
  cairo_surface_destroy(surface_);
  surface_ = nullptr;
  return out;
}

void raster_layer(cairo_t* cr, Format format, const Rect& r, const std::function<void(cairo_t*)>& draw) {
  if (format == Format::kPng) {
    draw(cr);
    return;
  }
  constexpr double kScale = 2;
  const int w = static_cast<int>(std::ceil(r.w * kScale)), h = static_cast<int>(std::ceil(r.h * kScale));
  cairo_surface_t* image = cairo_image_surface_create(CAIRO_FORMAT_ARGB32, std::max(w, 1), std::max(h, 1));
  cairo_t* c = cairo_create(image);
  cairo_scale(c, kScale, kScale);
  cairo_translate(c, -r.x, -r.y);
  draw(c);
  check(cairo_status(c), "drawing a layer failed");
  cairo_destroy(c);
  cairo_save(cr);
  cairo_translate(cr, r.x, r.y);
  cairo_scale(cr, 1 / kScale, 1 / kScale);
  cairo_set_source_surface(cr, image, 0, 0);
  cairo_paint(cr);
  cairo_restore(cr);
  cairo_surface_destroy(image);
}

void set_colour(cairo_t* cr, const Rgb& c, double alpha) { cairo_set_source_rgba(cr, c.r, c.g, c.b, alpha); }

void text(cairo_t* cr, const std::string& s, double x, double y, double size, double ax, double ay) {
  cairo_select_font_face(cr, "DejaVu Sans", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
  cairo_set_font_size(cr, size);
  cairo_text_extents_t e;
  cairo_text_extents(cr, s.c_str(), &e);
  // The baseline: ay = 1 puts it at y, ay = 0 the capitals' tops (0.72 of the size).
  cairo_move_to(cr, x - ax * e.x_advance, y + (1 - ay) * 0.72 * size);
  cairo_show_text(cr, s.c_str());
}

std::string number(double v) {
  char buf[32];
  const double a = std::abs(v);
  if (a != 0 && (a < 1e-2 || a >= 1e4))
    std::snprintf(buf, sizeof buf, "%.2e", v);
  else
    std::snprintf(buf, sizeof buf, "%.3g", v);
  return buf;
}

void colour_bar(cairo_t* cr, const ColourBar& bar, Rgb (*map)(double)) {
  const Rect& r = bar.rect;
  cairo_pattern_t* g = cairo_pattern_create_linear(0, r.y + r.h, 0, r.y);
  for (int k = 0; k <= 32; ++k) {
    const Rgb c = map(k / 32.0);
    cairo_pattern_add_color_stop_rgb(g, k / 32.0, c.r, c.g, c.b);
  }
  cairo_rectangle(cr, r.x, r.y, r.w, r.h);
  cairo_set_source(cr, g);
  cairo_fill(cr);
  cairo_pattern_destroy(g);
  cairo_set_source_rgb(cr, 0.2, 0.2, 0.2);
  cairo_set_line_width(cr, 0.6);
  cairo_rectangle(cr, r.x, r.y, r.w, r.h);
  cairo_stroke(cr);
  text(cr, number(bar.hi), r.x + r.w + 3, r.y, 10, 0, 0.5);
  text(cr, number(bar.lo), r.x + r.w + 3, r.y + r.h, 10, 0, 0.5);
  if (bar.lo < 0 && bar.hi > 0) {
    const double y0 = r.y + r.h * bar.hi / (bar.hi - bar.lo);
    text(cr, "0", r.x + r.w + 3, y0, 10, 0, 0.5);
  }
}

cairo_pattern_t* checker_pattern() {
  cairo_surface_t* s = cairo_image_surface_create(CAIRO_FORMAT_RGB24, 2, 2);
  cairo_t* cr = cairo_create(s);
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j) {
      set_colour(cr, checker_colour((i + j) % 2 == 1));
      cairo_rectangle(cr, i, j, 1, 1);
      cairo_fill(cr);
    }
  cairo_destroy(cr);
  cairo_pattern_t* p = cairo_pattern_create_for_surface(s);
  cairo_surface_destroy(s);
  cairo_pattern_set_extend(p, CAIRO_EXTEND_REPEAT);
  cairo_pattern_set_filter(p, CAIRO_FILTER_NEAREST);
  return p;
}

}  // namespace brenier::render::detail
