// One error type for the whole library: what went wrong and where (file, JSON path, device...).
#pragma once
#include <stdexcept>
#include <string>

namespace xi {

class Error : public std::runtime_error {
 public:
  Error(std::string what, std::string where = {})
      : std::runtime_error(where.empty() ? what : what + " (" + where + ")"),
        what_(std::move(what)),
        where_(std::move(where)) {}
  const std::string& message() const { return what_; }
  const std::string& where() const { return where_; }

 private:
  std::string what_;
  std::string where_;
};

}  // namespace xi
