"""rovlab.interfaces"""
