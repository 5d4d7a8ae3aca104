"""The C loop appended to a compiled function's library so that one call evaluates it ``n`` times
(:func:`batch_loop_c`; :func:`arvcas.build.codegen.build_described` with ``batch_loop=True`` appends it,
:func:`arvcas.build.calls.run_loop` calls it).
"""

from __future__ import annotations

import casadi as ca

__all__ = ["batch_loop_c"]


def batch_loop_c(f: ca.Function) -> str:
    """C appended to ``f``'s generated code: ``<name>_arvcas_batch``, a loop over ``n`` evaluations of ``f``.

    ``int <name>_arvcas_batch(long long n, long long chunk, long long* next, int* stop, long long* failed,
    const double* const* a, const long long* sa, double* const* r, const long long* sr, long long* iw,
    double* w)``: input ``k`` of evaluation ``i`` is ``a[k] + i * sa[k]`` (``sa[k] = 0``: all share it),
    output ``k`` goes to ``r[k] + i * sr[k]``; ``iw``, ``w``: the caller's work arrays (``f.sz_iw()``,
    ``f.sz_w()`` entries), one set per concurrent call. The evaluations are taken ``chunk`` at a time
    from the shared counter ``*next`` (atomically), so several threads calling it at once share the
    ``n`` evaluations dynamically; each stops before its next chunk once ``*stop`` is set (by another
    caller or by an interrupted Python), and a failed evaluation sets ``*stop``, stores its index in
    ``*failed`` and returns 1 (else 0). :func:`arvcas.build.calls.run_loop` calls it.
    """
    name = f.name()
    n_in, n_out = f.n_in(), f.n_out()
    return f"""
/* arvcas: {name} on n evaluations (arvcas.build.codegen.batch_loop_c) */
CASADI_SYMBOL_EXPORT int {name}_arvcas_batch(long long int n, long long int chunk, long long int* next, int* stop,
    long long int* failed, const casadi_real* const* a, const long long int* sa, casadi_real* const* r,
    const long long int* sr, casadi_int* iw, casadi_real* w) {{
  const casadi_real* arg[{max(f.sz_arg(), n_in, 1)}];
  casadi_real* res[{max(f.sz_res(), n_out, 1)}];
  long long int i, i0, i1;
  int k;
  for (;;) {{
    if (__atomic_load_n(stop, __ATOMIC_RELAXED)) return 0;
    i0 = __atomic_fetch_add(next, chunk, __ATOMIC_RELAXED);
    if (i0 >= n) return 0;
    i1 = i0 + chunk < n ? i0 + chunk : n;
    for (i = i0; i < i1; ++i) {{
      for (k = 0; k < {n_in}; ++k) arg[k] = a[k] + i * sa[k];
      for (k = 0; k < {n_out}; ++k) res[k] = r[k] + i * sr[k];
      if ({name}(arg, res, iw, w, 0)) {{
        *failed = i;
        __atomic_store_n(stop, 1, __ATOMIC_RELAXED);
        return 1;
      }}
    }}
  }}
}}
"""
