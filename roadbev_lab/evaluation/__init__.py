"""Evaluation: the metrics, scoring a bag's frames offline (``roadbev eval``) and online (over
DDS), the preview at arrival, and the evaluation and drive bags that carry the ground truth."""
