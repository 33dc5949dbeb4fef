"""Shared helpers below every other layer: conventions (angles; NED/FRD against ROS's ENU/FLU
frames), the component slots of the closed loop, and small numerical rules used by more than one
layer (Bryson's rule, atomic file writes). Nothing here imports another rovlab package."""
