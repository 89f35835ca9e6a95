"""The placement search: candidates a crane can make, and the strategies that choose among them.

* :mod:`.problem`: what a search is asked (:class:`~.problem.Problem`), the
  :class:`~.problem.Strategy` interface, and the typed :class:`~.problem.Phase`
  each strategy hands on;
* :mod:`.drop` and :mod:`.build`: lowering a block until it touches, and a
  layout under construction with its incremental checks;
* :mod:`.hangings`, :mod:`.patterns`, :mod:`.shapes` and :mod:`.sites`: how a
  block hangs from the crane, and where the placement pattern puts it;
* the strategies: :mod:`.beam`, :mod:`.anneal` and the CP-SAT bound
  :mod:`.cpsat`, scored by :mod:`.objective`;
* :mod:`.physics`: the local settle of a candidate and the final confirmation.

``optimizer.api.optimize`` runs them; it is the public entry point.
"""
