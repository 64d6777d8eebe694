// std::vector's allocator for large arrays that are filled after they are sized.
#pragma once
#include <memory>
#include <type_traits>
#include <utility>

namespace xi {

// An allocator whose vectors leave new elements default-initialised (plain data: unwritten) where
// std::allocator's zero them: a large array filled afterwards on every core is not first zeroed,
// its pages all faulted in, on one thread.
template <class T>
struct DefaultInitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <class U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

}  // namespace xi
