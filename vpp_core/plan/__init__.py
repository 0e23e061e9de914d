"""Plan stage: the pipeline part → candidates → R → S → cover → plan document (SPEC §5, §8).

pipeline (the stages in order), metrics (SPEC §5), diagnostics (faces that force views),
tour (visiting order), document (the request and plan document models), regions (regions of
interest: per-face targets, ignored faces), regionsdoc (the document's regions block).
Imports: every stage below it (cover, candidates, trace, camera, mesh) and the shared leaves.
"""
