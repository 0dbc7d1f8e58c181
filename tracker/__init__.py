"""Tracker: body model, kinematics, extremal contours, Jacobians, chamfer cost, solver, initialisation, renderer."""
