"""
Bench-only memory probe of the soaked node (``bench/soak.py --tracemalloc``); not the product.

``bench/soak.py`` puts this directory first on the node process's ``PYTHONPATH`` only when
asked, so Python imports it at start-up. With ``QFA_SOAK_TRACEMALLOC=DIR`` it starts
``tracemalloc`` (``QFA_SOAK_TRACEMALLOC_FRAMES`` frames, default 8) and a daemon thread that
dumps a snapshot to ``DIR/snapshot_NNNN.pickle`` every ``QFA_SOAK_TRACEMALLOC_PERIOD_S``
(default 300 s); ``bench/soak.py --snapshots DIR`` compares them. It adds one thread to the
node process and slows every allocation: measure slopes without it.
"""

import os

_DIRECTORY = os.environ.get('QFA_SOAK_TRACEMALLOC')

if _DIRECTORY:
    import threading
    import time
    import tracemalloc

    tracemalloc.start(int(os.environ.get('QFA_SOAK_TRACEMALLOC_FRAMES', '8')))

    def _dump(period_s=float(os.environ.get('QFA_SOAK_TRACEMALLOC_PERIOD_S', '300'))):
        index = 0
        while True:
            time.sleep(period_s)
            snapshot = tracemalloc.take_snapshot()
            path = os.path.join(_DIRECTORY, f'snapshot_{index:04d}.pickle')
            snapshot.dump(path + '.tmp')
            os.replace(path + '.tmp', path)
            index += 1

    threading.Thread(target=_dump, name='soak_tracemalloc', daemon=True).start()
