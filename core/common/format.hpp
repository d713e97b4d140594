// Decimal text of doubles for the files we write (meshes, CSV, reports): the shortest digits
// that read back as the same double (std::to_chars), so every value round-trips exactly, as
// with "%.17g", in fewer bytes and about a fifth of the time (bench/bench_format: 54 against
// 245 ns a value; bench/RESULTS.md, session 48). Not for cache keys: their text must not change.
#pragma once

#include <charconv>
#include <string>

namespace brenier {

inline void append_double(std::string& out, double x) {
  char buf[32];  // the longest shortest form, "-2.2250738585072014e-308", has 24
  const auto r = std::to_chars(buf, buf + sizeof buf, x);
  out.append(buf, r.ptr);
}

inline void append_int(std::string& out, long long x) {
  char buf[24];
  const auto r = std::to_chars(buf, buf + sizeof buf, x);
  out.append(buf, r.ptr);
}

inline std::string double_text(double x) {
  std::string s;
  append_double(s, x);
  return s;
}

}  // namespace brenier
