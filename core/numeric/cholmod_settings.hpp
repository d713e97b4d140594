// A CHOLMOD setting shared by the solvers whose kept Cholesky factor preconditions GMRES (the
// conformal map's Newton steps, the planar transport's).
#pragma once

#include <cholmod.h>

namespace brenier::numeric {

/// Makes every factorization of `c` end by converting its factor to a packed, monotonic
/// simplicial LL^T, with the zeros of the relaxed supernodes dropped (final_resymbol): the
/// numeric factorization keeps the supernodal kernels' speed, and each later solve takes the
/// simplicial one's. One right-hand side through a supernodal factor costs a dtrsv call per
/// supernode, and GMRES makes 20-60 such solves per factor (bench/RESULTS.md, session 53).
inline void convert_factors_for_solves(cholmod_common& c) {
  c.final_asis = 0;
  c.final_super = 0;
  c.final_ll = 1;
  c.final_pack = 1;
  c.final_monotonic = 1;
  c.final_resymbol = 1;
}

}  // namespace brenier::numeric
