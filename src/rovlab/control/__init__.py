"""Control (Sandøy 2016, sec. 5.2):

* ``lqr`` -- discrete LQR for depth and heading, Bryson's rule, reference feed-forward
* ``lqg`` -- the LQG law tau = P r - K [eta; nu] - b_hat (compiled kernel) and the thruster
             mapping of tau = [Z, N] through the allocation
"""
