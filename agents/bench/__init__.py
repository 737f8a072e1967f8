"""A controller on a lab's control stack: ophyd devices over EPICS, a Bluesky run
(``python -m agents.bench``)."""
