// Placeholder: filled in by the issue-3 work.
int main() { return 0; }
