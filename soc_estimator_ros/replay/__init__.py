"""``soc_replay``: recordings through the estimators, offline (``run``) or through a live node
(``live``); what it writes (``outputs``); the command line (``cli``)."""
