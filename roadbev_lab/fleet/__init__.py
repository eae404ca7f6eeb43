"""A fleet's bag archive: evaluate and label many bags at once, on a local pool or a Ray cluster.

``roadbev eval`` and ``roadbev label`` take many bags (a list, a directory, a glob) and run one
task per bag on an executor (:mod:`~roadbev_lab.fleet.executors`: in this process, a local
process pool, or a Ray cluster with ``--ray ADDRESS``). Every finished bag's result goes into a
result store (:mod:`~roadbev_lab.fleet.store`) under a key made of the bag's content and the
configuration, as it arrives: a bag that fails is reported with its reason and never stops the
others, and a run that is interrupted resumes where it stopped. The summary (:mod:`~roadbev_lab.fleet.summary`)
gives each bag's result as the one-bag command writes it and the pooled one, computed from the
bags' sums (:mod:`roadbev_lab.evaluation.pooled`).

Ray is an optional extra (``pip install .[fleet]``): only :class:`~roadbev_lab.fleet.executors.RayPool`
imports it, when it is made. The runtime (what a car runs) never imports any of this.
"""
