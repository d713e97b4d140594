#include "mesh/io.hpp"

#include <OpenMesh/Core/IO/IOManager.hh>
#include <OpenMesh/Core/IO/importer/BaseImporter.hh>
#include <OpenMesh/Core/System/omstream.hh>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <type_traits>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <mutex>
#include <sstream>
#include <vector>

#include "common/error.hpp"
#include "common/format.hpp"

namespace brenier::mesh {
namespace {

std::string lower(std::string_view s) {
  std::string out(s);
  std::transform(out.begin(), out.end(), out.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return out;
}

bool starts_with_ci(std::string_view s, std::string_view prefix) {
  return s.size() >= prefix.size() && lower(s.substr(0, prefix.size())) == prefix;
}

// ---------------------------------------------------------------------------------------
// Header guards. OpenMesh's readers trust the counts in OFF and PLY headers and the
// triangle count of binary STL; we check every declared count against the bytes actually
// present (each element needs at least a known number of bytes) before handing the data
// over, so a 40-byte file that declares 2^31 vertices is refused instead of looping or
// allocating.
// ---------------------------------------------------------------------------------------

// Splits the head of an ascii file into whitespace-separated tokens, skipping '#' comments,
// and remembers where the next unread byte is.
class Tokenizer {
 public:
  explicit Tokenizer(std::string_view s) : s_(s) {}
  std::optional<std::string_view> next() {
    for (;;) {
      while (pos_ < s_.size() && std::isspace(static_cast<unsigned char>(s_[pos_]))) ++pos_;
      if (pos_ < s_.size() && s_[pos_] == '#') {
        while (pos_ < s_.size() && s_[pos_] != '\n') ++pos_;
        continue;
      }
      break;
    }
    if (pos_ >= s_.size()) return std::nullopt;
    size_t b = pos_;
    while (pos_ < s_.size() && !std::isspace(static_cast<unsigned char>(s_[pos_]))) ++pos_;
    return s_.substr(b, pos_ - b);
  }
  size_t pos() const { return pos_; }

 private:
  std::string_view s_;
  size_t pos_ = 0;
};

uint32_t load_be32(const char* p) {
  uint32_t v;
  std::memcpy(&v, p, 4);
  if constexpr (std::endian::native == std::endian::little) v = __builtin_bswap32(v);
  return v;
}

std::optional<int64_t> parse_count(std::optional<std::string_view> tok) {
  if (!tok || tok->empty() || tok->size() > 18) return std::nullopt;
  int64_t v = 0;
  for (char c : *tok) {
    if (c < '0' || c > '9') return std::nullopt;
    v = v * 10 + (c - '0');
  }
  return v;
}

void check_limits(const char* fmt, int64_t nv, int64_t nf, const ReadLimits& limits) {
  if (nv > limits.max_vertices)
    fail(ErrorCode::kResourceExhausted, std::string(fmt) + " file declares " + std::to_string(nv) +
                                            " vertices, over the limit of " +
                                            std::to_string(limits.max_vertices));
  if (nf > limits.max_faces)
    fail(ErrorCode::kResourceExhausted, std::string(fmt) + " file declares " + std::to_string(nf) +
                                            " faces, over the limit of " +
                                            std::to_string(limits.max_faces));
}

void check_declared(const char* fmt, const char* what, int64_t count, int64_t min_bytes_each,
                    int64_t available) {
  // count * min_bytes_each > available, written without overflow.
  if (count < 0 || (min_bytes_each > 0 && count > available / min_bytes_each))
    invalid(std::string(fmt) + " file is truncated or corrupt: header declares " +
            std::to_string(count) + " " + what + " but only " + std::to_string(available) +
            " bytes follow the header");
}

// The OFF keyword is [ST][C][N][4][n]OFF, each prefix optional and in this order; anything
// else ("BINARYOFF", say) is not OFF.
bool is_off_keyword(std::string_view m) {
  if (!m.ends_with("OFF")) return false;
  m.remove_suffix(3);
  for (std::string_view part : {"ST", "C", "N", "4", "n"})
    if (m.starts_with(part)) m.remove_prefix(part.size());
  return m.empty();
}

// What guard_off found and checked: the reader starts at `body` and reads exactly `nv`
// vertices and `nf` faces, never re-parsing the header (a second parse that finds the counts
// elsewhere, e.g. "BINARY" inside the keyword "BINARYOFF", would read unchecked counts).
struct OffHeader {
  bool binary = false;
  int64_t nv = 0, nf = 0;
  size_t body = 0;          // offset of the first vertex (binary: of its first float)
  int64_t body_line = 0;    // lines before `body` (ascii error messages count from 1)
};

OffHeader guard_off(std::string_view bytes, const ReadLimits& limits) {
  Tokenizer tok(bytes);
  auto magic = tok.next();
  // Keyword [ST][C][N][4][n]OFF: case matters ('N' normals, 'n' a dimension follows).
  if (!magic || !is_off_keyword(*magic))
    invalid("OFF file does not start with an OFF keyword ([ST][C][N][4][n]OFF)");
  std::string_view m = *magic;
  if (m.find('4') != std::string_view::npos)
    invalid("OFF file is 4-dimensional (4OFF), not a surface in 3-D");
  const bool has_dim = m.size() >= 4 && m[m.size() - 4] == 'n';
  OffHeader h;
  Tokenizer peek = tok;
  if (auto t = peek.next(); t && *t == "BINARY") {
    h.binary = true;
    tok = peek;
  }
  if (has_dim && !h.binary) {
    auto dim = parse_count(tok.next());
    if (!dim || *dim != 3) invalid("OFF file declares a dimension other than 3");
  }
  if (h.binary) {
    // Binary OFF stores the counts as big-endian int32 on the line after the BINARY token.
    size_t p = bytes.find('\n', tok.pos());
    if (p == std::string_view::npos || bytes.size() - p - 1 < 12)
      invalid("binary OFF file is truncated in its header");
    ++p;
    h.nv = static_cast<int32_t>(load_be32(bytes.data() + p));
    h.nf = static_cast<int32_t>(load_be32(bytes.data() + p + 4));
    h.body = p + 12;
    check_limits("OFF", h.nv, h.nf, limits);
    int64_t avail = static_cast<int64_t>(bytes.size() - h.body);
    check_declared("binary OFF", "vertices", h.nv, 12, avail);
    check_declared("binary OFF", "faces", h.nf, 4, avail - h.nv * 12);
    return h;
  }
  auto nv = parse_count(tok.next());
  auto nf = parse_count(tok.next());
  auto ne = parse_count(tok.next());
  if (!nv || !nf || !ne)
    invalid("OFF header must give three non-negative counts (vertices faces edges)");
  h.nv = *nv;
  h.nf = *nf;
  check_limits("OFF", h.nv, h.nf, limits);
  // The body starts on the line after the counts (anything after them on their line, a
  // comment say, is not data).
  size_t nl = bytes.find('\n', tok.pos());
  h.body = nl == std::string_view::npos ? bytes.size() : nl + 1;
  h.body_line = std::count(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(h.body), '\n');
  int64_t avail = static_cast<int64_t>(bytes.size() - h.body);
  // An ascii vertex needs at least "x y z" plus a separator (6 bytes), a face "k" and a
  // separator (2 bytes).
  check_declared("OFF", "vertices", h.nv, 6, avail + 1);
  check_declared("OFF", "faces", h.nf, 2, avail + 1 - h.nv * 6);
  return h;
}

template <typename T>
int parse_numbers(std::string_view line, T* out, int n);

// PLY header: elements and their properties, checked against the bytes that follow.
enum class PlyType { kI8, kU8, kI16, kU16, kI32, kU32, kF32, kF64 };

std::optional<PlyType> ply_type(std::string_view t) {
  std::string s = lower(t);
  if (s == "char" || s == "int8") return PlyType::kI8;
  if (s == "uchar" || s == "uint8") return PlyType::kU8;
  if (s == "short" || s == "int16") return PlyType::kI16;
  if (s == "ushort" || s == "uint16") return PlyType::kU16;
  if (s == "int" || s == "int32") return PlyType::kI32;
  if (s == "uint" || s == "uint32") return PlyType::kU32;
  if (s == "float" || s == "float32") return PlyType::kF32;
  if (s == "double" || s == "float64") return PlyType::kF64;
  return std::nullopt;
}

int ply_size(PlyType t) {
  switch (t) {
    case PlyType::kI8: case PlyType::kU8: return 1;
    case PlyType::kI16: case PlyType::kU16: return 2;
    case PlyType::kI32: case PlyType::kU32: case PlyType::kF32: return 4;
    case PlyType::kF64: return 8;
  }
  return 1;
}

struct PlyProperty {
  std::string name;
  bool is_list = false;
  PlyType type = PlyType::kF32;  // item type
  PlyType count_type = PlyType::kU8;
};

struct PlyElement {
  std::string name;
  int64_t count = 0;
  std::vector<PlyProperty> props;
  int64_t min_bytes() const {  // per item
    int64_t n = 0;
    for (const auto& p : props) n += p.is_list ? ply_size(p.count_type) : ply_size(p.type);
    return std::max<int64_t>(n, 1);
  }
};

struct PlyHeader {
  enum class Encoding { kAscii, kLittle, kBig } encoding = Encoding::kAscii;
  std::vector<PlyElement> elements;
  size_t body = 0;  // offset of the first byte after "end_header\n"
};

PlyHeader guard_ply(std::string_view bytes, const ReadLimits& limits) {
  if (!bytes.starts_with("ply")) invalid("PLY file does not start with 'ply'");
  size_t end = bytes.find("end_header");
  if (end == std::string_view::npos || end > (size_t{1} << 20))
    invalid("PLY file has no end_header line");
  size_t body = bytes.find('\n', end);
  if (body == std::string_view::npos) invalid("PLY file ends right after its header");
  PlyHeader h;
  h.body = body + 1;
  std::istringstream in{std::string(bytes.substr(0, end))};
  std::string line;
  bool format_seen = false;
  int line_no = 0;
  auto where = [&] { return "PLY header line " + std::to_string(line_no) + ": "; };
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ls(line);
    std::string kw;
    ls >> kw;
    if (line_no == 1 || kw.empty() || kw == "comment" || kw == "obj_info") continue;
    if (kw == "format") {
      std::string f;
      ls >> f;
      if (f == "ascii") h.encoding = PlyHeader::Encoding::kAscii;
      else if (f == "binary_little_endian") h.encoding = PlyHeader::Encoding::kLittle;
      else if (f == "binary_big_endian") h.encoding = PlyHeader::Encoding::kBig;
      else invalid(where() + "unknown format '" + f + "'");
      format_seen = true;
    } else if (kw == "element") {
      std::string name, count;
      ls >> name >> count;
      auto n = parse_count(count);
      if (!n) invalid(where() + "element '" + name + "' has no valid count");
      h.elements.push_back({name, *n, {}});
    } else if (kw == "property") {
      if (h.elements.empty()) invalid(where() + "property before any element");
      std::string type;
      ls >> type;
      PlyProperty prop;
      if (type == "list") {
        std::string ct, it;
        ls >> ct >> it >> prop.name;
        auto c = ply_type(ct), i = ply_type(it);
        if (!c || !i) invalid(where() + "unknown list types '" + ct + "', '" + it + "'");
        if (*c == PlyType::kF32 || *c == PlyType::kF64)
          invalid(where() + "list count type must be an integer type");
        prop.is_list = true;
        prop.count_type = *c;
        prop.type = *i;
      } else {
        auto t = ply_type(type);
        if (!t) invalid(where() + "unknown property type '" + type + "'");
        prop.type = *t;
        ls >> prop.name;
      }
      h.elements.back().props.push_back(prop);
    } else {
      invalid(where() + "unknown keyword '" + kw + "'");
    }
  }
  if (!format_seen) invalid("PLY header has no format line");
  int64_t nv = 0, nf = 0;
  for (const auto& e : h.elements) {
    if (e.name == "vertex") nv = e.count;
    if (e.name == "face") nf = e.count;
  }
  check_limits("PLY", nv, nf, limits);
  // Each item needs at least min_bytes (binary) or one character and a separator per
  // property (ascii).
  const bool ascii = h.encoding == PlyHeader::Encoding::kAscii;
  int64_t avail = static_cast<int64_t>(bytes.size() - h.body) + (ascii ? 1 : 0);
  for (const auto& e : h.elements) {
    int64_t per = ascii ? 2 * static_cast<int64_t>(std::max<size_t>(e.props.size(), 1)) : e.min_bytes();
    std::string what = "'" + e.name + "' elements";
    check_declared("PLY", what.c_str(), e.count, per, avail);
    avail -= e.count * per;
  }
  return h;
}

// Reads PLY values one at a time from the body, ascii or binary, bounds-checked.
class PlyCursor {
 public:
  PlyCursor(std::string_view bytes, const PlyHeader& h)
      : s_(bytes), p_(h.body), enc_(h.encoding) {}

  double read(PlyType t) {
    if (enc_ == PlyHeader::Encoding::kAscii) return read_ascii();
    int n = ply_size(t);
    if (p_ + n > s_.size()) invalid("PLY file is truncated in its binary data");
    unsigned char b[8];
    std::memcpy(b, s_.data() + p_, n);
    p_ += n;
    bool swap = (enc_ == PlyHeader::Encoding::kBig) == (std::endian::native == std::endian::little);
    if (swap) std::reverse(b, b + n);
    switch (t) {
      case PlyType::kI8: { int8_t v; std::memcpy(&v, b, 1); return v; }
      case PlyType::kU8: { uint8_t v; std::memcpy(&v, b, 1); return v; }
      case PlyType::kI16: { int16_t v; std::memcpy(&v, b, 2); return v; }
      case PlyType::kU16: { uint16_t v; std::memcpy(&v, b, 2); return v; }
      case PlyType::kI32: { int32_t v; std::memcpy(&v, b, 4); return v; }
      case PlyType::kU32: { uint32_t v; std::memcpy(&v, b, 4); return v; }
      case PlyType::kF32: { float v; std::memcpy(&v, b, 4); return v; }
      case PlyType::kF64: { double v; std::memcpy(&v, b, 8); return v; }
    }
    return 0;
  }

 private:
  double read_ascii() {
    while (p_ < s_.size() && std::isspace(static_cast<unsigned char>(s_[p_]))) ++p_;
    if (p_ >= s_.size()) invalid("PLY file is truncated in its ascii data");
    size_t b = p_;
    while (p_ < s_.size() && !std::isspace(static_cast<unsigned char>(s_[p_]))) ++p_;
    std::string tok(s_.substr(b, p_ - b));
    char* stop = nullptr;
    double v = std::strtod(tok.c_str(), &stop);
    if (stop != tok.c_str() + tok.size()) invalid("PLY ascii data has a non-number '" + tok.substr(0, 32) + "'");
    return v;
  }

  std::string_view s_;
  size_t p_;
  PlyHeader::Encoding enc_;
};

// PLY reader of ours: OpenMesh 9's PLY reader narrows double coordinates to float.
PolygonSoup read_ply(std::string_view bytes, const ReadLimits& limits) {
  PlyHeader h = guard_ply(bytes, limits);
  PlyCursor cur(bytes, h);
  PolygonSoup soup;
  for (const auto& e : h.elements) {
    const bool is_vertex = e.name == "vertex", is_face = e.name == "face";
    int xyz[3] = {-1, -1, -1};
    int list = -1;
    for (size_t i = 0; i < e.props.size(); ++i) {
      const auto& pr = e.props[i];
      if (is_vertex && !pr.is_list) {
        if (pr.name == "x") xyz[0] = static_cast<int>(i);
        if (pr.name == "y") xyz[1] = static_cast<int>(i);
        if (pr.name == "z") xyz[2] = static_cast<int>(i);
      }
      if (is_face && pr.is_list && list < 0 &&
          (pr.name == "vertex_indices" || pr.name == "vertex_index"))
        list = static_cast<int>(i);
    }
    if (is_vertex && (xyz[0] < 0 || xyz[1] < 0 || xyz[2] < 0))
      invalid("PLY vertex element lacks an x, y or z property");
    if (is_face && list < 0) invalid("PLY face element has no vertex_indices list");
    if (is_vertex) soup.positions.reserve(static_cast<size_t>(e.count));
    for (int64_t item = 0; item < e.count; ++item) {
      Eigen::Vector3d p = Eigen::Vector3d::Zero();
      for (size_t i = 0; i < e.props.size(); ++i) {
        const auto& pr = e.props[i];
        if (!pr.is_list) {
          double v = cur.read(pr.type);
          for (int k = 0; k < 3; ++k)
            if (static_cast<int>(i) == xyz[k]) p[k] = v;
          continue;
        }
        double n = cur.read(pr.count_type);
        if (!(n >= 0) || n > static_cast<double>(bytes.size()))
          invalid("PLY " + e.name + " " + std::to_string(item) + " has an invalid list length");
        const int64_t k = static_cast<int64_t>(n);
        for (int64_t j = 0; j < k; ++j) {
          double v = cur.read(pr.type);
          if (static_cast<int>(i) == list) {
            if (v != std::floor(v) || std::abs(v) > 4e18)
              invalid("PLY face " + std::to_string(item) + " has a non-integer vertex index");
            soup.indices.push_back(static_cast<int64_t>(v));
          }
        }
        if (static_cast<int>(i) == list)
          soup.face_offsets.push_back(static_cast<int64_t>(soup.indices.size()));
      }
      if (is_vertex) soup.positions.push_back(p);
    }
  }
  return soup;
}

// OBJ reader of ours: OpenMesh 9's OBJ reader stores positions as float. Reads `v x y z`
// (extra values such as w or colours ignored) and `f` with i, i/t, i//n or i/t/n corners,
// negative indices counting back from the last vertex; every other statement is ignored.
PolygonSoup read_obj(std::string_view bytes, const ReadLimits& limits) {
  PolygonSoup soup;
  size_t pos = 0;
  int64_t line_no = 0;
  while (pos < bytes.size()) {
    size_t e = bytes.find('\n', pos);
    if (e == std::string_view::npos) e = bytes.size();
    std::string_view line = bytes.substr(pos, e - pos);
    pos = e + 1;
    ++line_no;
    size_t b = 0;
    while (b < line.size() && (line[b] == ' ' || line[b] == '\t')) ++b;
    line = line.substr(b);
    if (line.size() < 2 || (line[1] != ' ' && line[1] != '\t')) continue;
    auto where = [&] { return "OBJ line " + std::to_string(line_no) + ": "; };
    if (line[0] == 'v') {
      double xyz[3];
      if (parse_numbers(line.substr(2), xyz, 3) != 3)
        invalid(where() + "vertex needs three coordinates");
      if (static_cast<int64_t>(soup.positions.size()) >= limits.max_vertices)
        fail(ErrorCode::kResourceExhausted,
             "OBJ file has more than " + std::to_string(limits.max_vertices) + " vertices");
      soup.positions.emplace_back(xyz[0], xyz[1], xyz[2]);
    } else if (line[0] == 'f') {
      std::string_view rest = line.substr(2);
      size_t q = 0;
      int corners = 0;
      while (q < rest.size()) {
        while (q < rest.size() && std::isspace(static_cast<unsigned char>(rest[q]))) ++q;
        if (q >= rest.size()) break;
        size_t t = q;
        while (t < rest.size() && !std::isspace(static_cast<unsigned char>(rest[t]))) ++t;
        std::string_view tok = rest.substr(q, t - q);
        q = t;
        std::string idx(tok.substr(0, tok.find('/')));
        char* stop = nullptr;
        errno = 0;
        long long v = std::strtoll(idx.c_str(), &stop, 10);
        if (idx.empty() || stop != idx.c_str() + idx.size() || errno == ERANGE || v == 0)
          invalid(where() + "face corner '" + std::string(tok.substr(0, 32)) +
                  "' is not a vertex index (OBJ indices start at 1)");
        int64_t n = static_cast<int64_t>(soup.positions.size());
        soup.indices.push_back(v > 0 ? v - 1 : n + v);  // negative: relative to the end
        ++corners;
      }
      if (soup.num_faces() >= limits.max_faces)
        fail(ErrorCode::kResourceExhausted,
             "OBJ file has more than " + std::to_string(limits.max_faces) + " faces");
      soup.face_offsets.push_back(static_cast<int64_t>(soup.indices.size()));
      (void)corners;
    }
  }
  if (soup.positions.empty() && soup.num_faces() == 0 && !bytes.empty() &&
      bytes.find("v ") == std::string_view::npos)
    invalid("OBJ file has no vertex ('v') statements");
  return soup;
}

bool stl_is_binary(std::string_view bytes, const ReadLimits& limits) {
  if (bytes.size() >= 84) {
    uint32_t n = 0;
    std::memcpy(&n, bytes.data() + 80, 4);
    if constexpr (std::endian::native == std::endian::big) n = __builtin_bswap32(n);
    int64_t expect = 84 + int64_t{50} * n;
    if (expect == static_cast<int64_t>(bytes.size())) {
      check_limits("STL", 3 * int64_t{n}, n, limits);
      return true;
    }
    if (!starts_with_ci(bytes, "solid")) {
      invalid("binary STL file is truncated or corrupt: header declares " + std::to_string(n) +
              " triangles (" + std::to_string(expect) + " bytes) but the file has " +
              std::to_string(bytes.size()) + " bytes");
    }
  }
  if (!starts_with_ci(bytes, "solid")) invalid("STL file is neither binary nor ascii ('solid')");
  if (bytes.find("facet") == std::string_view::npos) invalid("ascii STL file has no facet");
  return false;
}

// ---------------------------------------------------------------------------------------
// OFF reader of ours. OpenMesh 9's OFF reader fails on files that CGAL's own data set holds:
// it loops forever on '#' comment lines before the keyword (cube-shuffled.off,
// sphere966.off), loses its place on comments between elements (cube_poly.off, prim.off) and
// on per-face colours after the indices (quint_tris.off). OFF is line-oriented in practice:
// a vertex line starts with x y z (normals, colours or texture coordinates may follow and
// are ignored), a face line with k i1 .. ik (a colour may follow and is ignored).
// ---------------------------------------------------------------------------------------

class LineReader {
 public:
  // `s` starts after `lines_before` lines of the file (for the line numbers in messages).
  explicit LineReader(std::string_view s, int64_t lines_before = 0)
      : s_(s), line_no_(lines_before) {}
  // Next line with its comment removed that has at least one token; nullopt at the end.
  std::optional<std::string_view> next() {
    while (pos_ < s_.size()) {
      size_t e = s_.find('\n', pos_);
      if (e == std::string_view::npos) e = s_.size();
      std::string_view line = s_.substr(pos_, e - pos_);
      pos_ = e + 1;
      ++line_no_;
      if (size_t h = line.find('#'); h != std::string_view::npos) line = line.substr(0, h);
      size_t b = 0;
      while (b < line.size() && std::isspace(static_cast<unsigned char>(line[b]))) ++b;
      if (b < line.size()) return line.substr(b);
    }
    return std::nullopt;
  }
  int64_t line_no() const { return line_no_; }
  size_t pos() const { return pos_; }

 private:
  std::string_view s_;
  size_t pos_ = 0;
  int64_t line_no_ = 0;
};

// Parses up to `n` numbers from the front of a line; returns how many were read.
template <typename T>
int parse_numbers(std::string_view line, T* out, int n) {
  const char* p = line.data();
  const char* end = line.data() + line.size();
  int got = 0;
  while (got < n) {
    while (p < end && std::isspace(static_cast<unsigned char>(*p))) ++p;
    if (p >= end) break;
    std::string_view rest(p, static_cast<size_t>(end - p));
    size_t len = 0;
    while (len < rest.size() && !std::isspace(static_cast<unsigned char>(rest[len]))) ++len;
    std::string tok(rest.substr(0, len));
    char* stop = nullptr;
    if constexpr (std::is_floating_point_v<T>) {
      double v = std::strtod(tok.c_str(), &stop);
      if (stop != tok.c_str() + tok.size()) break;
      out[got++] = static_cast<T>(v);
    } else {
      errno = 0;
      long long v = std::strtoll(tok.c_str(), &stop, 10);
      if (stop != tok.c_str() + tok.size() || errno == ERANGE) break;
      out[got++] = static_cast<T>(v);
    }
    p += len;
  }
  return got;
}

// Binary OFF body: float32 coordinates, then faces as int32 k, k int32 indices, int32
// number of colour components and that many float32 (all big-endian).
PolygonSoup read_off_binary(std::string_view bytes, const OffHeader& h) {
  size_t p = h.body;
  auto be32 = [&](size_t at) { return static_cast<int64_t>(static_cast<int32_t>(load_be32(bytes.data() + at))); };
  PolygonSoup soup;
  soup.positions.resize(static_cast<size_t>(h.nv));  // guard_off: 12 bytes each are present
  for (int64_t i = 0; i < h.nv; ++i, p += 12) {
    float xyz[3];
    for (int k = 0; k < 3; ++k) {
      uint32_t u = load_be32(bytes.data() + p + 4 * k);
      std::memcpy(&xyz[k], &u, 4);
    }
    soup.positions[i] = Eigen::Vector3d(xyz[0], xyz[1], xyz[2]);
  }
  for (int64_t f = 0; f < h.nf; ++f) {
    if (bytes.size() - p < 4) invalid("binary OFF file is truncated in face " + std::to_string(f));
    int64_t k = be32(p);
    p += 4;
    if (k < 0 || static_cast<uint64_t>(k) * 4 + 4 > bytes.size() - p)
      invalid("binary OFF file is truncated or corrupt in face " + std::to_string(f));
    for (int64_t i = 0; i < k; ++i, p += 4) soup.indices.push_back(be32(p));
    soup.face_offsets.push_back(static_cast<int64_t>(soup.indices.size()));
    int64_t nc = be32(p);
    p += 4;
    if (nc < 0 || nc > 4 || static_cast<uint64_t>(nc) * 4 > bytes.size() - p)
      invalid("binary OFF file is corrupt in the colour of face " + std::to_string(f));
    p += static_cast<size_t>(nc) * 4;
  }
  return soup;
}

PolygonSoup read_off(std::string_view bytes, const ReadLimits& limits) {
  const OffHeader h = guard_off(bytes, limits);
  if (h.binary) return read_off_binary(bytes, h);
  // The ascii body from the header's end: lines of "x y z ..." then "k i1 .. ik ...".
  LineReader lines(bytes.substr(h.body), h.body_line);
  auto where = [&] { return "OFF line " + std::to_string(lines.line_no()) + ": "; };
  PolygonSoup soup;
  soup.positions.reserve(static_cast<size_t>(h.nv));  // guard_off: 6 bytes each are present
  for (int64_t i = 0; i < h.nv; ++i) {
    auto l = lines.next();
    if (!l)
      invalid("OFF file is truncated: it declares " + std::to_string(h.nv) + " vertices but has " +
              std::to_string(i));
    double xyz[3];
    if (parse_numbers(*l, xyz, 3) != 3)
      invalid(where() + "vertex " + std::to_string(i) + " does not start with three numbers");
    soup.positions.emplace_back(xyz[0], xyz[1], xyz[2]);
  }
  soup.face_offsets.reserve(static_cast<size_t>(h.nf) + 1);
  std::vector<int64_t> buf;
  for (int64_t f = 0; f < h.nf; ++f) {
    auto l = lines.next();
    if (!l)
      invalid("OFF file is truncated: it declares " + std::to_string(h.nf) + " faces but has " +
              std::to_string(f));
    int64_t k = -1;
    // A line of k indices holds at least 2k bytes: k is bounded by the line it is on.
    if (parse_numbers(*l, &k, 1) != 1 || k < 0 || k > static_cast<int64_t>(l->size()))
      invalid(where() + "face " + std::to_string(f) + " does not start with its vertex count");
    buf.resize(static_cast<size_t>(k) + 1);
    if (parse_numbers(*l, buf.data(), static_cast<int>(k) + 1) != k + 1)
      invalid(where() + "face " + std::to_string(f) + " declares " + std::to_string(k) +
              " vertices but lists fewer");
    soup.indices.insert(soup.indices.end(), buf.begin() + 1, buf.end());
    soup.face_offsets.push_back(static_cast<int64_t>(soup.indices.size()));
  }
  return soup;
}

// ---------------------------------------------------------------------------------------
// OpenMesh bridge: an importer that records what the reader found, without building a
// half-edge structure (which would silently drop non-manifold faces that our validator
// must see and name).
// ---------------------------------------------------------------------------------------
class SoupImporter final : public OpenMesh::IO::BaseImporter {
 public:
  explicit SoupImporter(PolygonSoup& soup, const ReadLimits& limits)
      : soup_(soup), limits_(limits) {}

  OpenMesh::VertexHandle add_vertex(const OpenMesh::Vec3f& p) override {
    return add_vertex(OpenMesh::Vec3d(p[0], p[1], p[2]));
  }
  OpenMesh::VertexHandle add_vertex(const OpenMesh::Vec3d& p) override {
    if (static_cast<int64_t>(soup_.positions.size()) >= limits_.max_vertices) {
      over_limit_ = true;
      return OpenMesh::VertexHandle();
    }
    soup_.positions.emplace_back(p[0], p[1], p[2]);
    return OpenMesh::VertexHandle(static_cast<int>(soup_.positions.size()) - 1);
  }
  OpenMesh::VertexHandle add_vertex() override { return add_vertex(OpenMesh::Vec3d(0, 0, 0)); }
  OpenMesh::HalfedgeHandle add_edge(OpenMesh::VertexHandle, OpenMesh::VertexHandle) override {
    return OpenMesh::HalfedgeHandle();
  }
  OpenMesh::FaceHandle add_face(const VHandles& idx) override {
    if (soup_.num_faces() >= limits_.max_faces) {
      over_limit_ = true;
      return OpenMesh::FaceHandle();
    }
    for (const auto& vh : idx) soup_.indices.push_back(vh.idx());
    soup_.face_offsets.push_back(static_cast<int64_t>(soup_.indices.size()));
    return OpenMesh::FaceHandle(static_cast<int>(soup_.num_faces()) - 1);
  }
  OpenMesh::FaceHandle add_face(OpenMesh::HalfedgeHandle) override { return OpenMesh::FaceHandle(); }

  // Attributes we do not keep.
  void add_face_texcoords(OpenMesh::FaceHandle, OpenMesh::VertexHandle,
                          const std::vector<OpenMesh::Vec2f>&) override {}
  void add_face_texcoords(OpenMesh::FaceHandle, OpenMesh::VertexHandle,
                          const std::vector<OpenMesh::Vec3f>&) override {}
  void set_face_texindex(OpenMesh::FaceHandle, int) override {}
  void set_point(OpenMesh::VertexHandle vh, const OpenMesh::Vec3f& p) override {
    if (vh.is_valid() && static_cast<size_t>(vh.idx()) < soup_.positions.size())
      soup_.positions[vh.idx()] = Eigen::Vector3d(p[0], p[1], p[2]);
  }
  void set_halfedge(OpenMesh::VertexHandle, OpenMesh::HalfedgeHandle) override {}
  void set_normal(OpenMesh::VertexHandle, const OpenMesh::Vec3f&) override {}
  void set_normal(OpenMesh::VertexHandle, const OpenMesh::Vec3d&) override {}
  void set_color(OpenMesh::VertexHandle, const OpenMesh::Vec3uc&) override {}
  void set_color(OpenMesh::VertexHandle, const OpenMesh::Vec4uc&) override {}
  void set_color(OpenMesh::VertexHandle, const OpenMesh::Vec3f&) override {}
  void set_color(OpenMesh::VertexHandle, const OpenMesh::Vec4f&) override {}
  void set_texcoord(OpenMesh::VertexHandle, const OpenMesh::Vec2f&) override {}
  void set_status(OpenMesh::VertexHandle, const OpenMesh::Attributes::StatusInfo&) override {}
  void set_next(OpenMesh::HalfedgeHandle, OpenMesh::HalfedgeHandle) override {}
  void set_face(OpenMesh::HalfedgeHandle, OpenMesh::FaceHandle) override {}
  void request_face_texcoords2D() override {}
  void set_texcoord(OpenMesh::HalfedgeHandle, const OpenMesh::Vec2f&) override {}
  void set_texcoord(OpenMesh::VertexHandle, const OpenMesh::Vec3f&) override {}
  void set_texcoord(OpenMesh::HalfedgeHandle, const OpenMesh::Vec3f&) override {}
  void set_status(OpenMesh::HalfedgeHandle, const OpenMesh::Attributes::StatusInfo&) override {}
  void set_color(OpenMesh::EdgeHandle, const OpenMesh::Vec3uc&) override {}
  void set_color(OpenMesh::EdgeHandle, const OpenMesh::Vec4uc&) override {}
  void set_color(OpenMesh::EdgeHandle, const OpenMesh::Vec3f&) override {}
  void set_color(OpenMesh::EdgeHandle, const OpenMesh::Vec4f&) override {}
  void set_status(OpenMesh::EdgeHandle, const OpenMesh::Attributes::StatusInfo&) override {}
  void set_normal(OpenMesh::FaceHandle, const OpenMesh::Vec3f&) override {}
  void set_normal(OpenMesh::FaceHandle, const OpenMesh::Vec3d&) override {}
  void set_color(OpenMesh::FaceHandle, const OpenMesh::Vec3uc&) override {}
  void set_color(OpenMesh::FaceHandle, const OpenMesh::Vec4uc&) override {}
  void set_color(OpenMesh::FaceHandle, const OpenMesh::Vec3f&) override {}
  void set_color(OpenMesh::FaceHandle, const OpenMesh::Vec4f&) override {}
  void set_status(OpenMesh::FaceHandle, const OpenMesh::Attributes::StatusInfo&) override {}
  void add_texture_information(int, std::string) override {}

  // Header counts are untrusted: never reserve from them.
  void reserve(unsigned int, unsigned int, unsigned int) override {}
  size_t n_vertices() const override { return soup_.positions.size(); }
  size_t n_faces() const override { return static_cast<size_t>(soup_.num_faces()); }
  size_t n_edges() const override { return 0; }

  bool over_limit() const { return over_limit_; }

 private:
  PolygonSoup& soup_;
  const ReadLimits& limits_;
  bool over_limit_ = false;
};

// OpenMesh reports problems on its own streams; our tools print exactly one line, so they
// are silenced once for the process.
void silence_openmesh() {
  static std::once_flag once;
  std::call_once(once, [] {
    omerr().disable();
    omlog().disable();
    omout().disable();
  });
}

PolygonSoup read_with_openmesh(std::string_view bytes, Format format, const ReadLimits& limits) {
  silence_openmesh();
  OpenMesh::IO::Options opt;
  std::string ext;
  switch (format) {
    case Format::kStl:
      ext = "stl";
      if (stl_is_binary(bytes, limits)) opt += OpenMesh::IO::Options::Binary;
      break;
    case Format::kObj:
    case Format::kOff:
    case Format::kPly:
    case Format::kFreeSurfer:
      break;
  }
  PolygonSoup soup;
  SoupImporter importer(soup, limits);
  std::istringstream in{std::string(bytes), std::ios::in | std::ios::binary};
  bool ok = false;
  try {
    // OpenMesh's readers are process-wide singletons that keep the options of the file being
    // read in members: two threads reading at once (a matrix's workers, a server's uploads)
    // would share them. One read at a time.
    static std::mutex openmesh_mutex;
    std::lock_guard<std::mutex> lock(openmesh_mutex);
    ok = OpenMesh::IO::IOManager().read(in, ext, importer, opt);
  } catch (const std::exception& e) {
    invalid(std::string(format_name(format)) + " file could not be parsed: " + e.what());
  }
  if (importer.over_limit())
    fail(ErrorCode::kResourceExhausted,
         std::string(format_name(format)) + " file has more than " +
             std::to_string(limits.max_vertices) + " vertices or " +
             std::to_string(limits.max_faces) + " faces");
  if (!ok) invalid(std::string(format_name(format)) + " file is corrupt or truncated (parser failed)");
  return soup;
}

// ---------------------------------------------------------------------------------------
// FreeSurfer binary triangle surface (the format of lh.pial, rh.white, ...):
//   3 bytes magic 0xFF 0xFF 0xFE, a "created by ..." line ending in '\n' followed by a
//   second '\n', int32 #vertices, int32 #faces, #vertices x 3 float32, #faces x 3 int32,
//   everything big-endian; optional tags may follow and are ignored.
// ---------------------------------------------------------------------------------------
constexpr unsigned char kFsTriMagic[3] = {0xFF, 0xFF, 0xFE};
constexpr unsigned char kFsQuadMagic[3] = {0xFF, 0xFF, 0xFF};

void store_be32(std::string& out, uint32_t v) {
  if constexpr (std::endian::native == std::endian::little) v = __builtin_bswap32(v);
  out.append(reinterpret_cast<const char*>(&v), 4);
}

PolygonSoup read_freesurfer(std::string_view bytes, const ReadLimits& limits) {
  if (bytes.size() < 3 || std::memcmp(bytes.data(), kFsTriMagic, 3) != 0) {
    if (bytes.size() >= 3 && std::memcmp(bytes.data(), kFsQuadMagic, 3) == 0)
      invalid("FreeSurfer quadrangle surface (magic 0xFFFFFF) is not supported; convert it with "
              "mris_convert to a triangle surface");
    invalid("FreeSurfer file does not start with the triangle-surface magic 0xFFFFFE");
  }
  size_t p = 3;
  // The creation line is text; bound the search so a corrupt file cannot make us scan it all.
  size_t nl = bytes.find('\n', p);
  if (nl == std::string_view::npos || nl - p > 4096)
    invalid("FreeSurfer file is corrupt: no end of the 'created by' line");
  p = nl + 1;
  if (p >= bytes.size() || bytes[p] != '\n')
    invalid("FreeSurfer file is corrupt: the 'created by' line is not followed by an empty line");
  ++p;
  if (bytes.size() - p < 8) invalid("FreeSurfer file is truncated before its vertex and face counts");
  int64_t nv = static_cast<int32_t>(load_be32(bytes.data() + p));
  int64_t nf = static_cast<int32_t>(load_be32(bytes.data() + p + 4));
  p += 8;
  if (nv < 0 || nf < 0)
    invalid("FreeSurfer file is corrupt: negative counts (" + std::to_string(nv) + " vertices, " +
            std::to_string(nf) + " faces)");
  check_limits("FreeSurfer", nv, nf, limits);
  int64_t avail = static_cast<int64_t>(bytes.size() - p);
  if (nv * 12 + nf * 12 > avail)
    invalid("FreeSurfer file is truncated: it declares " + std::to_string(nv) + " vertices and " +
            std::to_string(nf) + " faces (" + std::to_string(nv * 12 + nf * 12) +
            " bytes) but only " + std::to_string(avail) + " bytes follow");
  PolygonSoup soup;
  soup.positions.resize(static_cast<size_t>(nv));
  for (int64_t i = 0; i < nv; ++i) {
    float xyz[3];
    for (int k = 0; k < 3; ++k) {
      uint32_t u = load_be32(bytes.data() + p);
      std::memcpy(&xyz[k], &u, 4);
      p += 4;
    }
    soup.positions[i] = Eigen::Vector3d(xyz[0], xyz[1], xyz[2]);
  }
  soup.indices.resize(static_cast<size_t>(nf) * 3);
  soup.face_offsets.resize(static_cast<size_t>(nf) + 1);
  for (int64_t f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) {
      soup.indices[3 * f + k] = static_cast<int32_t>(load_be32(bytes.data() + p));
      p += 4;
    }
    soup.face_offsets[f + 1] = 3 * (f + 1);
  }
  return soup;
}

std::string write_freesurfer(const TriMesh& m) {
  std::string out(reinterpret_cast<const char*>(kFsTriMagic), 3);
  out += "created by brenier\n\n";
  store_be32(out, static_cast<uint32_t>(m.V.rows()));
  store_be32(out, static_cast<uint32_t>(m.F.rows()));
  for (int i = 0; i < m.V.rows(); ++i)
    for (int k = 0; k < 3; ++k) {
      float x = static_cast<float>(m.V(i, k));
      uint32_t u;
      std::memcpy(&u, &x, 4);
      store_be32(out, u);
    }
  for (int f = 0; f < m.F.rows(); ++f)
    for (int k = 0; k < 3; ++k) store_be32(out, static_cast<uint32_t>(m.F(f, k)));
  return out;
}

// ---------------------------------------------------------------------------------------
// Writers. Ascii numbers are the shortest that read back exactly (common/format.hpp).
// ---------------------------------------------------------------------------------------

std::string write_obj(const TriMesh& m, const UV* uv) {
  std::string out;
  out.reserve(static_cast<size_t>(m.V.rows()) * 64 + static_cast<size_t>(m.F.rows()) * 32);
  out += "# written by brenier\n";
  for (int i = 0; i < m.V.rows(); ++i) {
    out += "v ";
    append_double(out, m.V(i, 0));
    out += ' ';
    append_double(out, m.V(i, 1));
    out += ' ';
    append_double(out, m.V(i, 2));
    out += '\n';
  }
  if (uv) {
    for (int i = 0; i < uv->rows(); ++i) {
      out += "vt ";
      append_double(out, (*uv)(i, 0));
      out += ' ';
      append_double(out, (*uv)(i, 1));
      out += '\n';
    }
  }
  for (int f = 0; f < m.F.rows(); ++f) {
    out += 'f';
    for (int k = 0; k < 3; ++k) {
      out += ' ';
      append_int(out, m.F(f, k) + 1);
      if (uv) {
        out += '/';
        append_int(out, m.F(f, k) + 1);
      }
    }
    out += '\n';
  }
  return out;
}

std::string write_off(const TriMesh& m) {
  std::string out = "OFF\n" + std::to_string(m.V.rows()) + " " + std::to_string(m.F.rows()) + " 0\n";
  for (int i = 0; i < m.V.rows(); ++i) {
    append_double(out, m.V(i, 0));
    out += ' ';
    append_double(out, m.V(i, 1));
    out += ' ';
    append_double(out, m.V(i, 2));
    out += '\n';
  }
  for (int f = 0; f < m.F.rows(); ++f) {
    out += '3';
    for (int k = 0; k < 3; ++k) {
      out += ' ';
      append_int(out, m.F(f, k));
    }
    out += '\n';
  }
  return out;
}

template <typename T>
void put_le(std::string& out, T v) {
  static_assert(std::endian::native == std::endian::little, "PLY writer assumes little endian");
  out.append(reinterpret_cast<const char*>(&v), sizeof v);
}

std::string write_ply(const TriMesh& m, const UV* uv) {
  std::string out = "ply\nformat binary_little_endian 1.0\ncomment written by brenier\n";
  out += "element vertex " + std::to_string(m.V.rows()) + "\n";
  out += "property double x\nproperty double y\nproperty double z\n";
  if (uv) out += "property double u\nproperty double v\n";
  out += "element face " + std::to_string(m.F.rows()) + "\n";
  out += "property list uchar int vertex_indices\nend_header\n";
  for (int i = 0; i < m.V.rows(); ++i) {
    for (int k = 0; k < 3; ++k) put_le<double>(out, m.V(i, k));
    if (uv) {
      put_le<double>(out, (*uv)(i, 0));
      put_le<double>(out, (*uv)(i, 1));
    }
  }
  for (int f = 0; f < m.F.rows(); ++f) {
    put_le<uint8_t>(out, 3);
    for (int k = 0; k < 3; ++k) put_le<int32_t>(out, m.F(f, k));
  }
  return out;
}

}  // namespace

const char* format_name(Format f) {
  switch (f) {
    case Format::kObj: return "OBJ";
    case Format::kOff: return "OFF";
    case Format::kPly: return "PLY";
    case Format::kStl: return "STL";
    case Format::kFreeSurfer: return "FreeSurfer";
  }
  return "unknown";
}

std::optional<Format> parse_format(std::string_view name) {
  std::string n = lower(name);
  if (!n.empty() && n[0] == '.') n.erase(0, 1);
  if (n == "obj") return Format::kObj;
  if (n == "off") return Format::kOff;
  if (n == "ply") return Format::kPly;
  if (n == "stl") return Format::kStl;
  if (n == "freesurfer" || n == "fs") return Format::kFreeSurfer;
  return std::nullopt;
}

Format detect_format(std::string_view path, std::string_view head) {
  if (head.size() >= 3 && (std::memcmp(head.data(), kFsTriMagic, 3) == 0 ||
                           std::memcmp(head.data(), kFsQuadMagic, 3) == 0))
    return Format::kFreeSurfer;
  std::string ext = std::filesystem::path(std::string(path)).extension().string();
  if (auto f = parse_format(ext)) return *f;
  // No known extension: look at the content.
  size_t i = 0;
  while (i < head.size() && std::isspace(static_cast<unsigned char>(head[i]))) ++i;
  std::string_view h = head.substr(i);
  if (starts_with_ci(h, "ply")) return Format::kPly;
  if (h.size() >= 3 && (h.substr(0, 3) == "OFF" || h.substr(0, 4) == "COFF" ||
                        h.substr(0, 4) == "NOFF"))
    return Format::kOff;
  if (starts_with_ci(h, "solid")) return Format::kStl;
  if (h.starts_with("v ") || h.starts_with("# ") || h.starts_with("o ") || h.starts_with("mtllib"))
    return Format::kObj;
  invalid("cannot tell the mesh format of '" + std::string(path) +
          "': use a .obj, .off, .ply or .stl extension or a FreeSurfer surface");
}

PolygonSoup read_soup(std::string_view bytes, Format format, const ReadLimits& limits) {
  if (static_cast<int64_t>(bytes.size()) > limits.max_bytes)
    fail(ErrorCode::kResourceExhausted, "mesh file of " + std::to_string(bytes.size()) +
                                            " bytes is over the limit of " +
                                            std::to_string(limits.max_bytes));
  if (bytes.empty()) invalid(std::string(format_name(format)) + " file is empty (0 bytes)");
  if (format == Format::kFreeSurfer) return read_freesurfer(bytes, limits);
  if (format == Format::kOff) return read_off(bytes, limits);
  if (format == Format::kPly) return read_ply(bytes, limits);
  if (format == Format::kObj) return read_obj(bytes, limits);
  return read_with_openmesh(bytes, format, limits);
}

std::string read_file_bytes(const std::string& path, const ReadLimits& limits) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) invalid("'" + path + "' is a directory, not a mesh file");
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(ErrorCode::kNotFound, "cannot open mesh file '" + path + "'");
  in.seekg(0, std::ios::end);
  std::streamoff size = in.tellg();
  if (size < 0) invalid("cannot read mesh file '" + path + "'");
  if (size > limits.max_bytes)
    fail(ErrorCode::kResourceExhausted, "mesh file '" + path + "' has " + std::to_string(size) +
                                            " bytes, over the limit of " +
                                            std::to_string(limits.max_bytes));
  in.seekg(0, std::ios::beg);
  std::string bytes(static_cast<size_t>(size), '\0');
  if (size > 0 && !in.read(bytes.data(), size)) invalid("cannot read mesh file '" + path + "'");
  return bytes;
}

PolygonSoup read_soup_file(const std::string& path, std::optional<Format> format,
                           const ReadLimits& limits) {
  std::string bytes = read_file_bytes(path, limits);
  Format f = format ? *format : detect_format(path, std::string_view(bytes).substr(0, 256));
  try {
    return read_soup(bytes, f, limits);
  } catch (const Error& e) {
    throw Error(e.code(), path + ": " + e.what());  // name the file in every read error
  }
}

std::string write_mesh_string(const TriMesh& mesh, Format format, const UV* uv) {
  if (uv && uv->rows() != mesh.V.rows())
    invalid("uv has " + std::to_string(uv->rows()) + " rows for " + std::to_string(mesh.V.rows()) +
            " vertices");
  switch (format) {
    case Format::kObj: return write_obj(mesh, uv);
    case Format::kOff: return write_off(mesh);
    case Format::kPly: return write_ply(mesh, uv);
    case Format::kFreeSurfer: return write_freesurfer(mesh);
    case Format::kStl: break;
  }
  invalid(std::string("writing ") + format_name(format) + " is not supported (use obj, ply or off)");
}

void write_mesh_file(const std::string& path, const TriMesh& mesh, const UV* uv,
                     std::optional<Format> format) {
  Format f;
  if (format) {
    f = *format;
  } else {
    std::string ext = std::filesystem::path(path).extension().string();
    auto pf = parse_format(ext);
    if (!pf) invalid("cannot tell the output format of '" + path + "' from its extension");
    f = *pf;
  }
  std::string data = write_mesh_string(mesh, f, uv);
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) invalid("cannot write '" + path + "'");
  out.write(data.data(), static_cast<std::streamsize>(data.size()));
  if (!out) invalid("cannot write '" + path + "' (disk full?)");
}

std::optional<UV> read_obj_uv(std::string_view text, int64_t vertices) {
  std::vector<double> uv;
  std::istringstream in{std::string(text)};
  std::string line;
  for (int64_t n = 1; std::getline(in, line); ++n) {
    if (line.rfind("vt ", 0) == 0) {
      std::istringstream l(line.substr(3));
      double u = 0, v = 0;
      if (!(l >> u >> v) || !std::isfinite(u) || !std::isfinite(v))
        invalid("line " + std::to_string(n) + ": a texture coordinate needs two finite numbers");
      uv.push_back(u);
      uv.push_back(v);
    } else if (line.rfind("f ", 0) == 0 && line.find('/') != std::string::npos) {
      std::istringstream l(line.substr(2));
      for (std::string corner; l >> corner;) {
        const size_t slash = corner.find('/');
        const size_t end = corner.find('/', slash + 1);
        if (slash != std::string::npos && corner.substr(slash + 1, end - slash - 1) != corner.substr(0, slash))
          invalid("line " + std::to_string(n) + ": texture coordinates are not one per vertex (corner " + corner + ")");
      }
    }
  }
  if (uv.empty()) return std::nullopt;
  if (static_cast<int64_t>(uv.size() / 2) != vertices)
    invalid(std::to_string(uv.size() / 2) + " texture coordinates for " + std::to_string(vertices) +
            " vertices: they are not one per vertex");
  return Eigen::Map<const UV>(uv.data(), static_cast<Eigen::Index>(uv.size() / 2), 2);
}

}  // namespace brenier::mesh
