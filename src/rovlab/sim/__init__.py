"""rovlab.sim"""
