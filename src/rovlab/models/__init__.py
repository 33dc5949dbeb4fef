"""rovlab.models"""
