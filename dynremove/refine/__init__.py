"""The default preset's engineered steps after the scans (not in the paper).

Each is a ``Params`` switch and a row of the ablation table:

* ``morphology``: clean-up of L (opening, closing, small components, holes).
* ``fields``: background displacement fields across L, source votes.
* ``mask``: border refinement of L (source votes, GrabCut onto colour edges).
* ``fill``: the dynamic region refilled from all sources (median, realignment).
"""
