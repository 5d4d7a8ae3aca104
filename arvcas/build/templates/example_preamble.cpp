// example.cpp: the same as example.c from C++, through the F_eval wrappers of @LIB@.h
// (named arguments, work arrays on the stack). Prints the same lines as example.c.
//
// Build: with CMake (CMakeLists.txt builds it as example_cpp; consumer/CMakeLists.txt builds it
// against an installed package through find_package(@LIB@)), or by hand:
//   c++ -I. example.cpp -L. -l@LIB@ -Wl,-rpath,. -lm -o example_cpp
#include <array>
#include <cstdio>
#include <vector>
#include "@LIB@.h"
#include "@LIB@_params.h"

namespace {
void print_vec(const char* kind, const char* fn, const char* name, const double* v, std::size_t n) {
  std::printf("%s %s %s :", kind, fn, name);
  for (std::size_t i = 0; i < n; ++i) std::printf(" %.17g", v[i]);
  std::printf("\n");
}
}  // namespace

int main() {
