// A Cairo drawing target that ends as PNG or SVG bytes, and the drawing pieces the pictures
// share (text, colour bars, the texture pattern). Internal to core/render.
#pragma once

#include <cairo.h>

#include <functional>
#include <memory>
#include <string>

#include "render/render.hpp"

namespace brenier::render::detail {

class Canvas {
 public:
  /// A white canvas of width x height pixels (SVG: points, one per pixel).
  Canvas(Format format, int width, int height);
  ~Canvas();
  Canvas(const Canvas&) = delete;
  Canvas& operator=(const Canvas&) = delete;
  cairo_t* cr() const { return cr_; }
  /// Finishes the drawing and returns the file's bytes (once).
  std::string finish();

 private:
  Format format_;
  std::string svg_;
  cairo_surface_t* surface_ = nullptr;
  cairo_t* cr_ = nullptr;
};

/// Throws Error(kInvalidArgument) for a size outside 64..16384 pixels.
void check_picture_size(int width, int height);
/// Draws `draw` (in the picture's coordinates) onto `cr`: directly for PNG; for SVG into a
/// raster of twice the picture's resolution over `r`, embedded as one image, so that a panel
/// of thousands of faces stays one picture element (bear's sphere map: 17.7 MB of SVG paths).
void raster_layer(cairo_t* cr, Format format, const Rect& r, const std::function<void(cairo_t*)>& draw);
void set_colour(cairo_t* cr, const Rgb& c, double alpha = 1);
/// Text with its anchor: ax = 0 left, 0.5 centre, 1 right; ay likewise from top to bottom.
void text(cairo_t* cr, const std::string& s, double x, double y, double size, double ax = 0, double ay = 1);
/// "1.23", "-4.5e-03": a short label of a value.
std::string number(double v);
/// A vertical colour bar from `map(0)` at the bottom to `map(1)` at the top, labelled with lo
/// and hi (and 0 where it lies strictly inside).
void colour_bar(cairo_t* cr, const ColourBar& bar, Rgb (*map)(double));
/// The checkerboard as a repeating two-by-two pattern, one square per pattern unit.
cairo_pattern_t* checker_pattern();

}  // namespace brenier::render::detail
