"""Search, scoring, batches and the command line.

* :mod:`optimizer.api`: ``optimize``, the one public entry point of the placement search;
* :mod:`optimizer.search`: the search itself (candidates, strategies, physics in the loop);
* :mod:`optimizer.score`: a trainee's layout scored against the reference, its report and figures;
* :mod:`optimizer.batch`: many saves scored, or many scenes optimized;
* :mod:`optimizer.cli`: the ``shoha`` command.

``optimizer`` imports ``settle`` and ``geometry``; neither imports it.
"""
