// The version of the numbers brenier computes.
#pragma once

namespace brenier {

/// Bumped whenever a change alters the bits of any result (a solver's path, a tolerance, a
/// predicate): per-shape results cached by content hash and matrix tiles carry it, so that
/// those of an older engine are neither reused after an upgrade nor merged with newer tiles.
/// 2: the OT solver refactors its preconditioner by the iterations spent on it.
/// 5: sphere maps: the local Tutte steps and the barrier repair refuse moves that change the
///    covering degree; crowded conformal maps transport from a spread start.
/// 6: Wasserstein transports also stop on the dual gap (ShapeOptions::cost_tolerance); the
///    sphere's local Tutte steps never lengthen a vertex's longest edge.
/// 7: sphere shapes carry their exact-distance source measure and quantization cost; the
///    surface transport starts its halving at four times the last accepted step and stops
///    on the dual gap too.
inline constexpr const char* kNumericsVersion = "7";

}  // namespace brenier
