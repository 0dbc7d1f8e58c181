"""Helpers shared by the test modules (session factories, fakes, stand-ins); no tests here."""
