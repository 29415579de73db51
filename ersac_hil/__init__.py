"""ersac_hil"""
