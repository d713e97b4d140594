// Whether transparent huge pages pay on this machine (session 48): the programs no longer ask
// glibc's malloc for them, because on this VM a fresh 2 MB page was far slower to fault than
// 512 small ones. Timed harness: maps N MB of anonymous memory three times in a row, with and
// without MADV_HUGEPAGE, and prints the seconds of the first write over it (page faults plus
// the kernel's zeroing) and of a second write (the memory already in place). Where the huge
// pages' first touch is not slower than the small pages', GLIBC_TUNABLES=
// glibc.malloc.hugetlb=1 is worth trying for large transports (README, Deployment).
//
// Usage: bench_first_touch [MB]   (default 400)
#include <sys/mman.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

bool touch(size_t bytes, bool huge) {
  void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (p == MAP_FAILED) return false;
  if (huge && ::madvise(p, bytes, MADV_HUGEPAGE) != 0) std::fprintf(stderr, "madvise(MADV_HUGEPAGE) refused\n");
  auto t0 = std::chrono::steady_clock::now();
  std::memset(p, 1, bytes);
  const double first = seconds_since(t0);
  t0 = std::chrono::steady_clock::now();
  std::memset(p, 2, bytes);
  const double again = seconds_since(t0);
  std::printf("%-11s %6zu MB: first write %.3f s (%.2f s per GB), second %.3f s\n", huge ? "huge pages" : "small pages",
              bytes >> 20, first, first * (1 << 30) / static_cast<double>(bytes), again);
  ::munmap(p, bytes);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  const long mb = argc > 1 ? std::strtol(argv[1], nullptr, 10) : 400;
  if (argc > 2 || mb <= 0 || mb > (1 << 20)) {
    std::fprintf(stderr, "bench_first_touch: expected one size in MB between 1 and 1048576\n");
    return 2;
  }
  const size_t bytes = static_cast<size_t>(mb) << 20;
  for (bool huge : {false, true})
    for (int run = 0; run < 3; ++run)
      if (!touch(bytes, huge)) {
        std::fprintf(stderr, "bench_first_touch: mmap of %ld MB failed\n", mb);
        return 1;
      }
  return 0;
}
