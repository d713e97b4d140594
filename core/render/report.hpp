// Self-contained HTML reports of results (issue 24): the pictures, the JSON report's figures
// as tables, and for a map an interactive 3-D view of the surface with the map's
// checkerboard (three.js, inlined when the report is made, so the page opens from a file
// with no network). No I/O but reading three.js.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "jobs/jobs.hpp"
#include "render/render.hpp"

namespace brenier::render {

/// three.js and its OrbitControls, from Debian's libjs-three (/usr/share/javascript/three),
/// or from the directory $BRENIER_THREE_JS_DIR holding three.min.js and
/// examples/js/controls/OrbitControls.js. Read once. Throws Error(kFailedPrecondition)
/// naming the missing file (install libjs-three).
const std::string& three_js();

/// A map's report: the title, the pictures of map_picture (PNG, inlined; `png` where the
/// caller drew it already, at the default size), the figures of map.report as tables, the
/// surface in 3-D with the checkerboard of its image.
std::string map_report_html(const jobs::MapOutcome& map, const std::string& name, const Picture* png = nullptr);
/// A matrix's report: the heat map and MDS picture, the matrix as a table, the figures of
/// `report` as tables.
std::string matrix_report_html(const MatrixFigure& matrix, const nlohmann::json& report);
/// Any other result (a distance): its figures as tables.
std::string figures_report_html(const std::string& title, const nlohmann::json& report);

}  // namespace brenier::render
