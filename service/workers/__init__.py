"""The workers (camera, segment, track): their loops, their parts and how a studio config builds them.
"""
