"""benchmarks/sample_cost.py: the Callgrind listing's parser and the page's arithmetic (the page itself is checked
against its committed JSON by tests/test_readme.py)."""

from script_helpers import load_script


def _module():
    return load_script("benchmarks/sample_cost.py")


LISTING = """\
--------------------------------------------------------------------------------
179,512,663 (100.0%)  PROGRAM TOTALS
--------------------------------------------------------------------------------
Ir                    file:function
--------------------------------------------------------------------------------
112,783,660 (62.83%)  ???:run_proposed_f9.constprop.0.isra.0 [/c/run_proposed-74b6.so]
 33,922,844 (18.90%)  *  ???:run_proposed_f8.constprop.0 [/c/run_proposed-74b6.so]
  8,019,868 ( 4.47%)  ./math/../sysdeps/ieee754/dbl-64/s_sin.c:__sincos_fma
  4,879,982 ( 2.72%)  ./math/../sysdeps/ieee754/dbl-64/s_sincos.c:__sincos_fma [/usr/lib/libm.so.6]
  1,203,202 ( 0.67%)  ???:run_proposed_copy [/c/run_proposed-74b6.so]
  1,626,614 ( 0.91%)  ./math/../sysdeps/x86/fpu/fenv_private.h:__sincos_fma
"""


def test_parse_exclusive_adds_a_functions_files_and_strips_clone_suffixes():
    m = _module()
    r = m.parse_annotate(LISTING, inclusive=False)
    assert r["run_proposed_f9"] == 112_783_660
    assert r["run_proposed_f8"] == 33_922_844
    assert r["__sincos_fma"] == 8_019_868 + 4_879_982 + 1_626_614  # a line without its library too
    assert r["run_proposed_copy"] == 1_203_202
    assert "PROGRAM" not in " ".join(r)


def test_parse_inclusive_takes_a_functions_first_line():
    r = _module().parse_annotate(LISTING, inclusive=True)
    assert r["__sincos_fma"] == 8_019_868


def test_own_code_is_the_sample_less_what_it_calls():
    m = _module()
    f = {"cl_step_proposed": {"inclusive": 100.0}, "cl_rk4": {"inclusive": 60.0}, "cl_ok": {"inclusive": 5.0},
         "cl_thr_wrench": {"inclusive": 20.0}}
    assert m._own({"functions": f}) == 15.0
