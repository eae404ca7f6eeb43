"""The lab: what the team runs to measure and improve the runtime, never what a car runs.

The runtime (:mod:`roadbev_core`, :mod:`msg_bridge`, :mod:`roadbev_ros`) never imports this
package (``tests/package/test_layout.py`` checks it); the lab imports the runtime.

- :mod:`roadbev_lab.synth`: synthetic roads, scenes, drives and their renderer.
- :mod:`roadbev_lab.training`: datasets and training of the learned backends.
- :mod:`roadbev_lab.data`: real datasets (KITTI, RSRD) and LiDAR labels.
- :mod:`roadbev_lab.evaluation`: metrics, scoring of bags offline and online, preview at arrival.
- :mod:`roadbev_lab.ride`: the ride simulation that scores a preview.
- :mod:`roadbev_lab.reports`: figures and HTML reports.
- :mod:`roadbev_lab.demo`: ``roadbev demo``.
"""
