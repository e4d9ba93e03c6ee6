"""``python -m dynremove``: the ``dynremove`` command (``entry.main``)."""

from dynremove.entry import main

raise SystemExit(main())
