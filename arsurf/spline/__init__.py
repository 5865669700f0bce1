"""spline"""
