#include "test_hooks.hpp"

#include <array>
#include <mutex>

namespace brenier::server::test_hooks {
namespace {
std::mutex mutex;
std::array<std::function<void()>, static_cast<size_t>(Point::kCount)> armed;
}  // namespace

namespace detail {
std::atomic<bool> any_armed{false};

void fire(Point point) {
  std::function<void()> fn;
  {
    std::lock_guard<std::mutex> lock(mutex);
    fn.swap(armed[static_cast<size_t>(point)]);
  }
  if (fn) fn();
}
}  // namespace detail

void arm(Point point, std::function<void()> fn) {
  std::lock_guard<std::mutex> lock(mutex);
  armed[static_cast<size_t>(point)] = std::move(fn);
  detail::any_armed = true;
}

void disarm_all() {
  std::lock_guard<std::mutex> lock(mutex);
  for (auto& f : armed) f = nullptr;
  detail::any_armed = false;
}

}  // namespace brenier::server::test_hooks
