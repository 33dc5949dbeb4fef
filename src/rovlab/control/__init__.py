"""rovlab.control"""
