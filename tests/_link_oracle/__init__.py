"""The hand-derived single link: the independent oracle of the generic model-file path.

The paper's single-link flexible manipulator built by hand in Exudyn in hub-frame
coordinates (:mod:`_link_oracle.exudyn_link`), its periodic orbit by collocation
(:mod:`_link_oracle.link_orbit`), its finite-difference linearisation
(:mod:`_link_oracle.along_orbit`), Floquet multipliers and the direct Exudyn monodromy
(:mod:`_link_oracle.link_floquet`), the decay-fit nonlinear check
(:mod:`_link_oracle.closed_loop`, :mod:`_link_oracle.decay_study`), the nonlinear
multiplier measurement on this route (:mod:`_link_oracle.link_multipliers`) and the
side-by-side model comparison (:mod:`_link_oracle.model_comparison`).

None of it is on the product's path: ``--model exudyn`` is the built-in model file
``single-link``.  The tests compare that generic path against this one.  Scripts and
benchmarks that use the oracle put ``tests/`` on ``sys.path`` first.
"""
