"""rovlab.ident"""
