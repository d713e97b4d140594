// Named points in the server's concurrent code where a test can run its own code, to hold a
// race window open and make an interleaving reproducible (issue 20's regression tests). In a
// running brenierd nothing is ever armed: a hook costs one relaxed atomic load.
#pragma once

#include <atomic>
#include <functional>

namespace brenier::server::test_hooks {

enum class Point {
  kLiveBetweenLookups,  // Manager::live: between the live-map lookup and the store read
  kMeshBeforeRow,       // Store::put_mesh_with_blob: the blob is in place, the row not yet
  kSubmitAfterInsert,   // Manager::submit: the job row exists, not yet queued
  kRunStart,            // Manager::run: a worker took a job, before it starts it
  kLoadAfterRow,        // JobContext::load: the mesh row was read, its bytes not yet
  kCount
};

/// Runs `fn` the next time `point` is reached (once; then the point is disarmed).
void arm(Point point, std::function<void()> fn);
/// Disarms every point.
void disarm_all();

namespace detail {
extern std::atomic<bool> any_armed;
void fire(Point point);
}  // namespace detail

inline void at(Point point) {
  if (detail::any_armed.load(std::memory_order_relaxed)) detail::fire(point);
}

}  // namespace brenier::server::test_hooks
