"""Plan stage: the pipeline part → candidates → R → S → cover → plan document (SPEC §5, §8).

pipeline (the stages in order), metrics (SPEC §5), diagnostics (faces that force views),
tour (visiting order), document (the request and plan document models).
Imports: every stage below it (cover, candidates, trace, camera, mesh) and the shared leaves.
"""
