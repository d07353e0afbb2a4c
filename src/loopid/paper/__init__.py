"""The paper's reproduction: Ross & Bagnell's Figure 2 and the reading study, which span two
families (the helicopter and the finite MDP) and so live beside them rather than in one.

- :mod:`.commands`: ``loopid reproduce`` (Figure 2's three panels, every method, and the
  finite-MDP study beside them) and ``loopid study``;
- :mod:`.study`: the reading study's plan and run; :mod:`.study_readings`, the readings it
  compares; :mod:`.study_report`, ``study.md`` and its figures.
"""
