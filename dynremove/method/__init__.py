"""The method of the paper (Kanojia & Raman, WACV), Sec. 3, and nothing else.

* ``features``: dense SIFT f_g and the Lab mean f_c of every p×p patch (Sec. 3.1).
* ``geometry``: keypoint matches, F_s, H_s, the Sampson distance.
* ``correspondence``: the dense map N_{r→s} of every source.
* ``scan``: the alternating scans (Algorithm 1): compiled kernels, a readable
  reference, and the driver that flushes events to a sink.

The engineered steps of the default preset live in ``dynremove.refine``.
"""
