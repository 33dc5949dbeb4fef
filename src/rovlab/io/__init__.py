"""rovlab.io"""
