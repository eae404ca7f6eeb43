"""Figures and the HTML reports of the demo and of drives."""
