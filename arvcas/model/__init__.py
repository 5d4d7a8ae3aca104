"""Models as CasADi expression graphs (pure functions over SX, MX and DM alike).

- :mod:`.spatial`: rotations, Euler-angle kinematics J(eta), spatial transforms;
- :mod:`.vehicle`: Fossen's vehicle terms M, C(nu), D(nu), g(eta) (paper eq. 1, Appendix A);
- :mod:`.thrusters`: thrust allocation and saturation (eq. 2, Appendix B), command maps, the thruster lag;
- :mod:`.hydro`: Gauss-Legendre quadrature of the links' drag, buoyancy;
- :mod:`.manipulator`: modified DH, recursive Newton-Euler on the moving base (eq. 7-11);
- :mod:`.water`: an irrotational current as relative velocity (Fossen 2011, ch. 10), a quasi-static tether;
- :mod:`.uvms`: the exactly coupled vehicle + arm and the public plant functions;
- :mod:`.linalg`: small dense factorisations written in the graph.
"""
