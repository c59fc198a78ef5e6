// Placeholder: written in issue 4.
