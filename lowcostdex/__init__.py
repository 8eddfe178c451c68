"""lowcostdex"""
