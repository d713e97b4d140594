#include "render/report.hpp"

#include <openssl/evp.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <mutex>

#include "common/error.hpp"
#include "common/format.hpp"

namespace brenier::render {
namespace {

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in)
    fail(ErrorCode::kFailedPrecondition,
         "cannot read " + path + " for the HTML report's 3-D view (install libjs-three, or set BRENIER_THREE_JS_DIR)");
  return std::string(std::istreambuf_iterator<char>(in), {});
}

std::string base64(const void* data, size_t n) {
  std::string out(4 * ((n + 2) / 3) + 1, '\0');
  const int len = EVP_EncodeBlock(reinterpret_cast<unsigned char*>(out.data()),
                                  static_cast<const unsigned char*>(data), static_cast<int>(n));
  out.resize(static_cast<size_t>(len));
  return out;
}

std::string escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

// JSON inside <script type="application/json">: "</" would end the element.
std::string script_json(const nlohmann::json& j) {
  std::string s = j.dump();
  for (size_t at = 0; (at = s.find("</", at)) != std::string::npos; at += 3) s.replace(at, 2, "<\\/");
  return s;
}

// One row per leaf of the JSON: data-key the dotted path, data-value the exact value (JSON
// text), the cell the value as a reader wants it (6 significant digits).
void rows(const nlohmann::json& j, const std::string& key, std::string& out) {
  if (j.is_object()) {
    for (auto it = j.begin(); it != j.end(); ++it) rows(it.value(), key.empty() ? it.key() : key + "." + it.key(), out);
    return;
  }
  if (j.is_array() && !j.empty() && (j.front().is_object() || j.front().is_array())) {
    for (size_t i = 0; i < j.size(); ++i) rows(j[i], key + "." + std::to_string(i), out);
    return;
  }
  std::string shown;
  if (j.is_number_float()) {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.6g", j.get<double>());
    shown = buf;
  } else if (j.is_string()) {
    shown = j.get<std::string>();
  } else {
    shown = j.dump();
  }
  const std::string value = j.is_number_float() ? double_text(j.get<double>()) : j.dump();
  out += "<tr data-key=\"" + escape(key) + "\" data-value=\"" + escape(value) + "\"><th>" + escape(key) + "</th><td>" +
         escape(shown) + "</td></tr>\n";
}

// The figures: a table per section (top-level object), the top-level values first.
std::string figures(const nlohmann::json& report) {
  std::string out = "<section id=\"figures\"><h2>Figures</h2>\n";
  std::string top;
  for (auto it = report.begin(); it != report.end(); ++it)
    if (!it.value().is_object()) rows(it.value(), it.key(), top);
  if (!top.empty()) out += "<table class=\"figures\">\n" + top + "</table>\n";
  for (auto it = report.begin(); it != report.end(); ++it) {
    if (!it.value().is_object()) continue;
    std::string body;
    rows(it.value(), it.key(), body);
    out += "<h3>" + escape(it.key()) + "</h3>\n<table class=\"figures\">\n" + body + "</table>\n";
  }
  out += "<script type=\"application/json\" id=\"report-json\">" + script_json(report) + "</script>\n</section>\n";
  return out;
}

std::string page(const std::string& title, const std::string& body) {
  return "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>" + escape(title) +
         "</title>\n<style>\nbody{font-family:'DejaVu Sans',sans-serif;margin:1.5em;color:#222}\n"
         "table{border-collapse:collapse;margin:0.3em 0 1em}th,td{border:1px solid #ccc;padding:2px 8px;"
         "text-align:left;font-size:13px}th{font-weight:normal;color:#555}td{font-family:monospace}\n"
         "img{max-width:100%}canvas{border:1px solid #ccc}\n</style></head>\n<body>\n<h1>" +
         escape(title) + "</h1>\n" + body + "</body></html>\n";
}

std::string picture(const Picture& p, const std::string& alt) {
  return "<section id=\"pictures\"><img id=\"preview\" width=\"" + std::to_string(p.layout.width) + "\" alt=\"" +
         escape(alt) + "\" src=\"data:image/png;base64," + base64(p.bytes.data(), p.bytes.size()) + "\"></section>\n";
}

// The viewer: the surface as an indexed mesh whose fragments take the checker of their
// image point (the same squares as the pictures: 1/8 in (u, v), or 15 degrees of longitude
// and latitude), lit by a headlight; OrbitControls to turn and zoom.
constexpr const char* kViewer = R"JS(
(function () {
  const data = JSON.parse(document.getElementById('mesh-data').textContent);
  function decode(text, Type) {
    const bin = atob(text), bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; ++i) bytes[i] = bin.charCodeAt(i);
    return new Type(bytes.buffer);
  }
  const canvas = document.getElementById('surface');
  const renderer = new THREE.WebGLRenderer({canvas: canvas, antialias: true, preserveDrawingBuffer: true});
  renderer.setClearColor(0xffffff, 1);
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(decode(data.positions, Float32Array), 3));
  geometry.setAttribute('image', new THREE.BufferAttribute(decode(data.image, Float32Array), 3));
  geometry.setIndex(new THREE.BufferAttribute(decode(data.faces, Uint32Array), 1));
  geometry.computeVertexNormals();
  geometry.computeBoundingSphere();
  const material = new THREE.ShaderMaterial({
    uniforms: {disk: {value: data.disk ? 1.0 : 0.0}},
    side: THREE.DoubleSide,
    vertexShader: [
      'attribute vec3 image;', 'varying vec3 vImage;', 'varying vec3 vNormal;',
      'void main() {', '  vImage = image;', '  vNormal = normalize(normalMatrix * normal);',
      '  gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0);', '}'].join('\n'),
    fragmentShader: [
      'uniform float disk;', 'varying vec3 vImage;', 'varying vec3 vNormal;',
      'void main() {', '  float p;',
      '  if (disk > 0.5) { p = mod(floor(8.0 * vImage.x) + floor(8.0 * vImage.y), 2.0); }',
      '  else { vec3 s = normalize(vImage); float step = 3.14159265 / 12.0;',
      '    p = mod(floor(atan(s.y, s.x) / step) + floor(asin(clamp(s.z, -1.0, 1.0)) / step), 2.0); }',
      '  vec3 c = p > 0.5 ? vec3(0.16, 0.33, 0.62) : vec3(0.97, 0.93, 0.80);',
      '  gl_FragColor = vec4(c * (0.3 + 0.7 * abs(normalize(vNormal).z)), 1.0);', '}'].join('\n')
  });
  const scene = new THREE.Scene();
  scene.add(new THREE.Mesh(geometry, material));
  const s = geometry.boundingSphere, v = data.toward, u = data.up;
  const camera = new THREE.PerspectiveCamera(30, canvas.width / canvas.height, s.radius * 0.01, s.radius * 100);
  camera.up.set(u[0], u[1], u[2]);
  camera.position.set(s.center.x + 4 * s.radius * v[0], s.center.y + 4 * s.radius * v[1], s.center.z + 4 * s.radius * v[2]);
  const controls = new THREE.OrbitControls(camera, canvas);
  controls.target.copy(s.center);
  controls.update();
  function draw() { renderer.render(scene, camera); }
  controls.addEventListener('change', draw);
  draw();
  window.brenierView = {vertices: geometry.attributes.position.count, faces: geometry.index.count / 3};
})();
)JS";

std::string viewer(const mesh::TriMesh& surface, const mesh::Vertices& image, bool disk, const Eigen::Vector3d& toward,
                   const Eigen::Vector3d& up) {
  const Eigen::Matrix<float, Eigen::Dynamic, 3, Eigen::RowMajor> p = surface.V.cast<float>(), x = image.cast<float>();
  const Eigen::Matrix<uint32_t, Eigen::Dynamic, 3, Eigen::RowMajor> f = surface.F.cast<uint32_t>();
  const nlohmann::json data{{"positions", base64(p.data(), sizeof(float) * static_cast<size_t>(p.size()))},
                            {"image", base64(x.data(), sizeof(float) * static_cast<size_t>(x.size()))},
                            {"faces", base64(f.data(), sizeof(uint32_t) * static_cast<size_t>(f.size()))},
                            {"disk", disk},
                            {"toward", {toward.x(), toward.y(), toward.z()}},
                            {"up", {up.x(), up.y(), up.z()}}};
  return "<section id=\"view\"><h2>The surface with the map's checkerboard (drag to turn, wheel to zoom)</h2>\n"
         "<canvas id=\"surface\" width=\"720\" height=\"540\"></canvas></section>\n"
         "<script type=\"application/json\" id=\"mesh-data\">" +
         script_json(data) + "</script>\n<script>" + three_js() + "</script>\n<script>" + kViewer + "</script>\n";
}

}  // namespace

const std::string& three_js() {
  static std::once_flag once;
  static std::string js;
  std::call_once(once, [] {
    const char* env = std::getenv("BRENIER_THREE_JS_DIR");
    const std::string dir = env && *env ? env : "/usr/share/javascript/three";
    std::string three = read_text(dir + "/three.min.js"), orbit = read_text(dir + "/examples/js/controls/OrbitControls.js");
    // Inline scripts end at "</script": neither library has one, but make sure.
    for (std::string* s : {&three, &orbit})
      for (size_t at = 0; (at = s->find("</script", at)) != std::string::npos; at += 3) s->replace(at, 2, "<\\/");
    js = three + "\n" + orbit;
  });
  return js;
}

std::string map_report_html(const jobs::MapOutcome& map, const std::string& name, const Picture* png) {
  const std::vector<MapFigure> rows = map_figures(map, name);
  const Picture p = png ? *png : default_map_picture(rows, Format::kPng);
  const SurfaceView v = surface_view(map.surface, View{});
  const std::string title = "brenier: " + rows.back().title;
  return page(title, viewer(map.surface, map.positions, map.disk, v.toward, v.up) + picture(p, title) +
                         figures(map.report));
}

std::string matrix_report_html(const MatrixFigure& m, const nlohmann::json& report) {
  const Picture p = matrix_picture(m, Format::kPng, kMatrixPictureWidth, kMatrixPictureHeight);
  const std::vector<int> order = matrix_order(m);
  std::string table = "<section id=\"matrix\"><h2>Distances</h2><table class=\"matrix\"><tr><th></th>";
  for (int j : order) table += "<th>" + escape(m.names[static_cast<size_t>(j)]) + "</th>";
  table += "</tr>\n";
  for (int i : order) {
    table += "<tr><th>" + escape(m.names[static_cast<size_t>(i)]) + "</th>";
    for (int j : order) {
      char buf[40];
      std::snprintf(buf, sizeof buf, "%.6g", m.d(i, j));
      table += "<td data-value=\"" + double_text(m.d(i, j)) + "\">" + buf + "</td>";
    }
    table += "</tr>\n";
  }
  table += "</table></section>\n";
  const std::string title = "brenier: distances of " + std::to_string(m.d.rows()) + " shapes";
  return page(title, picture(p, title) + table + figures(report));
}

std::string figures_report_html(const std::string& title, const nlohmann::json& report) {
  return page(title, figures(report));
}

}  // namespace brenier::render
