// The main() of every GoogleTest binary here: GoogleTest's own, after the one start-up
// setting the tests must share with the programs they test. OpenBLAS's kernels decide how
// CHOLMOD's supernodal factorizations round, and the programs pin them where OpenBLAS does
// not know the CPU (process::choose_blas_kernels). Tests run without it would check
// different numbers than brenier-compute and brenierd compute.
#include <gtest/gtest.h>
#include <unistd.h>

#include "process.hpp"

int main(int argc, char** argv) {
  if (brenier::process::choose_blas_kernels()) ::execv("/proc/self/exe", argv);
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
