"""A trainee's layout scored against the reference (``shoha score``, docs/scoring.md).

* :mod:`.scoring`: the score and its penalties (:func:`score`, :class:`Reference`,
  :class:`ScoreWeights`);
* :mod:`.interlock`: what each block touches, and which blocks are poorly held;
* :mod:`.report`: the self-contained HTML report;
* :mod:`.render`: plan and section figures for print.
"""

from .scoring import Reference, ScoreReport, ScoreWeights, check_same_scene, score

__all__ = ["Reference", "ScoreReport", "ScoreWeights", "check_same_scene", "score"]
