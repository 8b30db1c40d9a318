"""The paper's experiments: protocols, drives, studies, their analysis, tables and figures."""
