/* example.c: call every function of lib@LIB@ at a fixed state, through CasADi's calling convention
 * with work arrays from F_work() (the pattern for threads: one set of arrays per thread), and print
 * inputs and outputs as lines 'in|out <function> <name> : values' with %.17g (they read back exactly).
 *
 * Build and run: make && ./example   (or with CMake: see CMakeLists.txt)
 */
#include <stdio.h>
#include <stdlib.h>
#include "@LIB@.h"
#include "@LIB@_params.h"

typedef int (*eval_t)(const casadi_real**, casadi_real**, casadi_int*, casadi_real*, int);
typedef int (*work_t)(casadi_int*, casadi_int*, casadi_int*, casadi_int*);

static int call(eval_t f, work_t work, const casadi_real** in, int n_in, casadi_real** out, int n_out)
{
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  if (work(&sz_arg, &sz_res, &sz_iw, &sz_w)) return 1;
  const casadi_real** arg = calloc(sz_arg > n_in ? sz_arg : n_in, sizeof *arg);
  casadi_real** res = calloc(sz_res > n_out ? sz_res : n_out, sizeof *res);
  casadi_int* iw = calloc(sz_iw + 1, sizeof *iw);
  casadi_real* w = calloc(sz_w + 1, sizeof *w);
  int flag = 1;
  if (arg && res && iw && w) {
    for (int i = 0; i < n_in; ++i) arg[i] = in[i];
    for (int i = 0; i < n_out; ++i) res[i] = out[i];
    flag = f(arg, res, iw, w, 0);
  }
  free(arg); free(res); free(iw); free(w);
  return flag;
}

static void print_vec(const char* kind, const char* fn, const char* name, const casadi_real* v, int n)
{
  printf("%s %s %s :", kind, fn, name);
  for (int i = 0; i < n; ++i) printf(" %.17g", v[i]);
  printf("\n");
}

