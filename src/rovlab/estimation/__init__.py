"""rovlab.estimation"""
